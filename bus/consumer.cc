#include "bus/consumer.h"

#include <csignal>

#include "bus/auth.h"

namespace stackgen {

status ConsumerStatus(const Bus& bus, const ConsumerReport& report) {
  status message{};
  message.header.seq = -1;
  message.header.generator_id = -1;
  message.header.utime = UnixMicros();
  message.next_seq = -1;
  message.process = report.process;
  message.name = report.name;
  message.scenes_held = report.scenes_held;
  message.scenes = report.scenes;
  message.rate_hz = report.rate_hz;
  message.received = report.delivery.received;
  message.duplicates = report.delivery.duplicates;
  message.lost = report.delivery.lost;
  message.reasked = report.delivery.reasked;
  message.bad_messages = report.bad_messages;
  message.fault_dropped = bus.fault_dropped();
  const AuthCounters refused = bus.auth_counters();
  message.refused_unsigned = refused.unsigned_messages;
  message.refused_forged = refused.forged;
  message.refused_replayed = refused.replayed;
  return message;
}

BusOptions ConsumerBusOptions(double fault_drop, const std::string& key_file, bool open_bus,
                              bool replay, uint64_t fault_seed) {
  BusOptions options;
  options.drop_receive_fraction = fault_drop;
  options.fault_seed = fault_seed;
  options.key_file = key_file;
  options.open_bus = open_bus;
  options.replay = replay;
  return options;
}

void StopOnSignals(void (*handler)(int)) {
  struct sigaction action {};
  action.sa_handler = handler;
  action.sa_flags = SA_RESTART;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
}

}  // namespace stackgen
