#include "session/consumer.h"

#include <csignal>
#include <cstdio>
#include <stdexcept>

#include "bus/auth.h"
#include "bus/channels.h"

namespace stackgen {

ConsumerSession::ConsumerSession(std::unique_ptr<Bus> bus, ConsumerSessionOptions options)
    : options_(std::move(options)),
      bus_(std::move(bus)),
      live_(bus_->url().rfind("file://", 0) != 0),
      clock_(options_.clock != nullptr ? options_.clock : &SteadyClock()) {
  if (options_.generator_channels.empty()) {
    options_.generator_channels = {kSceneChannel, kConfigChannel};
  }
  if (options_.reliable && live_) {
    SceneClientOptions client = options_.client;
    client.name = options_.name;
    if (client.clock == nullptr) client.clock = options_.clock;
    client_ = std::make_unique<SceneClient>(bus_.get(), client);
  }
  last_status_ = clock_->Now();
}

ConsumerSession::~ConsumerSession() = default;

Subscription ConsumerSession::SubscribeScenes(
    const std::string& channel, std::function<void(const scene&)> handler, int queue_capacity,
    std::function<void(const std::string&)> on_undecodable) {
  return bus_->Subscribe<scene>(
      channel,
      [this, handler = std::move(handler)](const scene& message) {
        ++received_;
        handler(message);
      },
      queue_capacity,
      [this, on_undecodable = std::move(on_undecodable)](const std::string& text) {
        ++undecodable_;
        if (on_undecodable) on_undecodable(text);
      });
}

void ConsumerSession::WatchGeneratorKeys() { bus_->state().WatchKeys(options_.generator_channels); }

bool ConsumerSession::Fresh(int32_t generator_id, int64_t seq) {
  const std::pair<int32_t, int64_t> key{generator_id, seq};
  if (client_) {
    if (!client_->Received(generator_id, seq)) {
      ++repeats_;
      return false;
    }
    bad_copies_.Forget(generator_id, seq);
    return true;
  }
  if (!recent_.insert(key).second) {
    ++repeats_;
    return false;
  }
  recent_order_.push_back(key);
  if (recent_order_.size() > options_.recent_scenes) {
    recent_.erase(recent_order_.front());
    recent_order_.pop_front();
  }
  return true;
}

void ConsumerSession::Refuse(int32_t generator_id, int64_t seq) {
  ++refused_;
  if (!client_ || !bad_copies_.Note(generator_id, seq)) return;
  // a seq the consumer holds a good copy of is pending or stored: Received is false
  if (client_->Received(generator_id, seq)) client_->Skipped(generator_id, seq);
}

void ConsumerSession::Stored(int32_t generator_id, int64_t seq) {
  if (client_) client_->Stored(generator_id, seq);
}

void ConsumerSession::Skipped(int32_t generator_id, int64_t seq) {
  if (client_) client_->Skipped(generator_id, seq);
}

void ConsumerSession::Passed(int32_t generator_id, int64_t seq) {
  if (client_) client_->Received(generator_id, seq);
}

void ConsumerSession::Restore(int32_t generator_id, const std::vector<int64_t>& seqs) {
  if (client_) client_->Restore(generator_id, seqs);
}

void ConsumerSession::SetRun(int32_t generator_id, const std::string& run) {
  if (client_) client_->SetRun(generator_id, run);
}

void ConsumerSession::Credit() {
  if (client_) client_->Service();
}

int64_t ConsumerSession::StoredThrough(int32_t generator_id) const {
  return client_ ? client_->StoredThrough(generator_id) : -1;
}

std::string ConsumerSession::KeyHint() const {
  if (!client_ && !bus_->state().keyed() && !options_.strict_keys) return "";
  return bus_->state().KeyMismatch(options_.generator_channels, 0);
}

void ConsumerSession::CheckKeys() const {
  const std::string mismatch = KeyHint();
  if (!mismatch.empty()) throw std::runtime_error(mismatch);
}

void ConsumerSession::Service(int64_t held, int64_t taken) {
  Credit();
  if (live_ && (client_ || bus_->state().keyed() || options_.strict_keys)) {
    // said, never a reason to stop: none of it is verified. An open consumer, which verifies
    // nothing, stops (its keyed generators refuse its credits, or it their scenes)
    const std::string mismatch =
        bus_->state().KeyMismatch(options_.generator_channels, options_.key_mismatch_s);
    if (!bus_->state().keyed() && !mismatch.empty()) throw std::runtime_error(mismatch);
    if (!keys_said_ && !mismatch.empty()) {
      std::fprintf(stderr, "%s: warning: %s; still waiting\n", options_.process.c_str(),
                   mismatch.c_str());
      keys_said_ = true;
    } else if (keys_said_ && KeyHint().empty()) {
      keys_said_ = false;  // a message of this key came
    }
  }
  if (held_at_last_status_ < 0) held_at_last_status_ = held;
  if (live_ && options_.status_period_s > 0 &&
      clock_->Now() - last_status_ >= std::chrono::duration<double>(options_.status_period_s)) {
    PublishStatus(held, taken, kRunRunning);
  }
}

void ConsumerSession::PublishStatus(int64_t held, int64_t taken, int8_t run_state) {
  const Clock::TimePoint now = clock_->Now();
  const double seconds = std::chrono::duration<double>(now - last_status_).count();
  if (held_at_last_status_ < 0) held_at_last_status_ = held;
  ConsumerReport report;
  report.process = options_.process;
  report.name = options_.name;
  report.scenes_held = held;
  report.scenes = taken;
  report.rate_hz = seconds > 0 ? static_cast<double>(held - held_at_last_status_) / seconds : 0;
  report.delivery = delivery();
  report.bad_messages = undecodable_ + refused_;
  report.run_state = run_state;
  bus_->Publish(kStatusChannel, ConsumerStatus(*bus_, report));
  last_status_ = now;
  held_at_last_status_ = held;
}

void ConsumerSession::Leave(int64_t held, int64_t taken, int8_t run_state) {
  if (!live_) return;
  if (options_.status_period_s > 0) PublishStatus(held, taken, run_state);
  if (client_) client_->Leave();
}

DeliveryCounters ConsumerSession::delivery() const {
  if (client_) return client_->counters();
  DeliveryCounters counters;
  counters.received = received_;
  counters.duplicates = repeats_;
  return counters;
}

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
  message.fault_dropped = bus.state().fault_dropped();
  const AuthCounters refused = bus.state().auth_counters();
  message.refused_unsigned = refused.unsigned_messages;
  message.refused_forged = refused.forged;
  message.refused_replayed = refused.replayed;
  message.refused_relayed = refused.relayed;
  message.run_state = report.run_state;
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
