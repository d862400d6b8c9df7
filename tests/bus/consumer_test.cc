#include "bus/consumer.h"

#include <atomic>
#include <csignal>
#include <string>

#include <gtest/gtest.h>

#include "bus/bus.h"

namespace stackgen {
namespace {

// a seq is given up at its third bad copy, not before; a good copy forgets the bad ones; two
// generators' seqs are kept apart; the memory is bounded
TEST(BadCopiesTest, GivesUpAtTheThirdBadCopy) {
  BadCopies bad;
  EXPECT_FALSE(bad.Note(0, 5));
  EXPECT_FALSE(bad.Note(0, 5));
  EXPECT_FALSE(bad.Note(1, 5));  // another generator's seq 5
  EXPECT_TRUE(bad.Note(0, 5));
  EXPECT_FALSE(bad.Note(0, 5));  // counted afresh after giving up
  bad.Forget(1, 5);
  EXPECT_FALSE(bad.Note(1, 5));
  EXPECT_FALSE(bad.Note(1, 5));
  EXPECT_TRUE(bad.Note(1, 5));
  for (int64_t seq = 0; seq < 10000; ++seq) bad.Note(2, seq);
  EXPECT_LE(bad.size(), BadCopies::kMaxSeqs);
}

// the status of a consumer: its report, no generator or seq, the bus's counters
TEST(ConsumerStatusTest, HoldsTheReportAndTheBusCounters) {
  BusOptions options;
  options.open_bus = true;
  Bus bus("memq://", options);
  ConsumerReport report;
  report.process = "stackgen-coco";
  report.name = "stackgen-coco@host:/data";
  report.scenes_held = 12;
  report.scenes = 10;
  report.rate_hz = 2.5;
  report.delivery.received = 11;
  report.delivery.duplicates = 1;
  report.delivery.lost = 2;
  report.delivery.reasked = 3;
  report.bad_messages = 4;
  const status message = ConsumerStatus(bus, report);
  EXPECT_EQ(message.header.seq, -1);
  EXPECT_EQ(message.header.generator_id, -1);
  EXPECT_EQ(message.next_seq, -1);
  EXPECT_GT(message.header.utime, 0);
  EXPECT_EQ(message.process, "stackgen-coco");
  EXPECT_EQ(message.name, "stackgen-coco@host:/data");
  EXPECT_EQ(message.scenes_held, 12);
  EXPECT_EQ(message.scenes, 10);
  EXPECT_DOUBLE_EQ(message.rate_hz, 2.5);
  EXPECT_EQ(message.received, 11);
  EXPECT_EQ(message.duplicates, 1);
  EXPECT_EQ(message.lost, 2);
  EXPECT_EQ(message.reasked, 3);
  EXPECT_EQ(message.bad_messages, 4);
  EXPECT_EQ(message.fault_dropped, bus.fault_dropped());
  EXPECT_EQ(message.refused_unsigned, 0);
}

// a consumer's flags become its bus options, the fault seed its own
TEST(ConsumerBusOptionsTest, FlagsBecomeBusOptions) {
  const BusOptions options = ConsumerBusOptions(0.25, "/keys/bus.key", true, true, 0xFEED);
  EXPECT_EQ(options.drop_receive_fraction, 0.25);
  EXPECT_EQ(options.key_file, "/keys/bus.key");
  EXPECT_TRUE(options.open_bus);
  EXPECT_TRUE(options.replay);
  EXPECT_EQ(options.fault_seed, 0xFEEDu);
  const BusOptions plain = ConsumerBusOptions(0, "", false, false, 1);
  EXPECT_EQ(plain.drop_receive_fraction, 0);
  EXPECT_FALSE(plain.open_bus);
  EXPECT_FALSE(plain.replay);
}

std::atomic<int> signals_seen{0};
void CountSignal(int) { ++signals_seen; }

// SIGINT and SIGTERM reach the handler, and the process goes on
TEST(StopOnSignalsTest, BothSignalsReachTheHandler) {
  struct sigaction old_int {
  }, old_term{};
  sigaction(SIGINT, nullptr, &old_int);
  sigaction(SIGTERM, nullptr, &old_term);
  StopOnSignals(CountSignal);
  raise(SIGINT);
  raise(SIGTERM);
  EXPECT_EQ(signals_seen.load(), 2);
  sigaction(SIGINT, &old_int, nullptr);
  sigaction(SIGTERM, &old_term, nullptr);
}

}  // namespace
}  // namespace stackgen
