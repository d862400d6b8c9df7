#include "session/consumer.h"

#include <atomic>
#include <csignal>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <stackgen/header.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/clock.h"

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
  report.run_state = kRunStopped;
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
  EXPECT_EQ(message.run_state, kRunStopped);
  EXPECT_EQ(message.fault_dropped, bus.state().fault_dropped());
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

std::unique_ptr<Bus> OpenMemq() {
  BusOptions options;
  options.open_bus = true;
  return std::make_unique<Bus>("memq://", options);
}

// a best-effort session: a repeat is one of the last recent_scenes; refusals, repeats, scenes
// and what did not decode are counted; the status goes out once per period of its clock, with
// the rate of scenes held over that period, and when it leaves
TEST(ConsumerSessionTest, BestEffortCountsWhatItHeardAndPublishesStatusEachPeriod) {
  ManualClock clock;
  ConsumerSessionOptions options;
  options.process = "stackgen-view";
  options.name = "stackgen-view/1";
  options.recent_scenes = 2;
  options.clock = &clock;
  ConsumerSession session(OpenMemq(), options);
  EXPECT_FALSE(session.reliable());
  EXPECT_TRUE(session.live());
  std::vector<status> statuses;
  session.bus().Subscribe<status>(kStatusChannel,
                                  [&](const status& message) { statuses.push_back(message); });
  int handled = 0;
  std::vector<std::string> undecodable;
  const Subscription scenes = session.SubscribeScenes(
      kSceneChannel, [&](const scene&) { ++handled; }, 16,
      [&](const std::string& text) { undecodable.push_back(text); });
  session.bus().Publish(kSceneChannel, scene{});
  session.bus().Publish(kSceneChannel, header{});  // not a scene
  session.bus().HandleFor(0);
  EXPECT_EQ(handled, 1);
  EXPECT_EQ(session.received(), 1);
  ASSERT_EQ(undecodable.size(), 1u);
  EXPECT_EQ(session.undecodable(), 1);

  EXPECT_TRUE(session.Fresh(0, 0));
  EXPECT_FALSE(session.Fresh(0, 0));
  EXPECT_TRUE(session.Fresh(0, 1));
  EXPECT_TRUE(session.Fresh(1, 0));  // another generator's seq 0
  EXPECT_TRUE(session.Fresh(0, 0));  // two newer ones since: forgotten
  session.Refuse(0, 2);
  EXPECT_EQ(session.repeats(), 1);
  EXPECT_EQ(session.refused(), 1);

  session.Service(3, 3);
  clock.Advance(0.6);
  session.Service(4, 4);
  session.bus().HandleFor(0);
  EXPECT_TRUE(statuses.empty());
  clock.Advance(0.4);
  session.Service(5, 5);
  session.bus().HandleFor(0);
  ASSERT_EQ(statuses.size(), 1u);
  EXPECT_EQ(statuses[0].process, "stackgen-view");
  EXPECT_EQ(statuses[0].name, "stackgen-view/1");
  EXPECT_EQ(statuses[0].scenes_held, 5);
  EXPECT_DOUBLE_EQ(statuses[0].rate_hz, 2.0);  // 3 -> 5 in 1 s
  EXPECT_EQ(statuses[0].received, 1);
  EXPECT_EQ(statuses[0].duplicates, 1);
  EXPECT_EQ(statuses[0].bad_messages, 2);
  EXPECT_EQ(statuses[0].run_state, kRunRunning);
  // the last status says how the run ended (a monitor shows it ended, not gone quiet)
  session.Leave(5, 5, kRunEnded);
  session.bus().HandleFor(0);
  ASSERT_EQ(statuses.size(), 2u);
  EXPECT_EQ(statuses[1].run_state, kRunEnded);
  EXPECT_EQ(statuses[1].scenes_held, 5);
}

// a reliable session: a seq whose copies keep failing is given up at the third bad copy (the
// client stops asking for it), but not one a good copy of which came first; a good copy is new
// once
TEST(ConsumerSessionTest, ReliableGivesUpASeqAtItsThirdBadCopyUnlessHeld) {
  ManualClock clock;
  ConsumerSessionOptions options;
  options.process = "stackgen-coco";
  options.name = "stackgen-coco@test";
  options.reliable = true;
  options.status_period_s = 0;
  options.clock = &clock;
  ConsumerSession session(OpenMemq(), options);
  ASSERT_TRUE(session.reliable());
  session.Refuse(0, 0);
  session.Refuse(0, 0);
  EXPECT_EQ(session.StoredThrough(0), -1);
  session.Refuse(0, 0);
  EXPECT_EQ(session.StoredThrough(0), 0);  // given up
  EXPECT_TRUE(session.Fresh(0, 1));
  for (int k = 0; k < 3; ++k) session.Refuse(0, 1);
  EXPECT_EQ(session.StoredThrough(0), 0);
  session.Stored(0, 1);
  EXPECT_EQ(session.StoredThrough(0), 1);
  EXPECT_FALSE(session.Fresh(0, 1));
  EXPECT_EQ(session.repeats(), 1);
  EXPECT_EQ(session.refused(), 6);
  EXPECT_EQ(session.delivery().stored, 1);
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
