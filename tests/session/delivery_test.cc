#include "session/delivery.h"

#include <map>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <stackgen/credit.hpp>
#include <stackgen/resend_request.hpp>
#include <stackgen/scene.hpp>

#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/clock.h"
#include "cli/flags.h"

namespace stackgen {
namespace {

// a small scene: only the header matters to delivery
std::vector<uint8_t> EncodedScene(int32_t generator_id, int64_t seq) {
  scene message{};
  message.header.seq = seq;
  message.header.generator_id = generator_id;
  message.header.seed = seq * 7 + 1;
  return EncodeMessage(message);
}

// a generator, a reliable consumer and the link between them, all on one memq:// bus, their
// timers on one manual clock (time passes when the test says so). The test decides which scene
// messages the consumer gets to see (`drop`), like a lossy network would.
class DeliveryFixture : public ::testing::Test {
 protected:
  void SetUpLink(SceneServerOptions server_options, SceneClientOptions client_options,
                 BusOptions bus_options = {}) {
    server_options.clock = &clock_;
    client_options.clock = &clock_;
    bus_options.clock = &clock_;
    bus_ = std::make_unique<Bus>("memq://", bus_options);
    server_ = std::make_unique<SceneServer>(
        bus_.get(), server_options,
        [this, id = server_options.generator_id](int64_t seq) {
          regenerated_.push_back(seq);
          return EncodedScene(id, seq);
        },
        [this](const std::string& line) { notices_.push_back(line); });
    client_ = std::make_unique<SceneClient>(bus_.get(), client_options);
    bus_->Subscribe<scene>(kSceneChannel, [this](const scene& message) {
      const int32_t id = message.header.generator_id;
      const int64_t seq = message.header.seq;
      ++arrivals_[{id, seq}];
      if (drop_.erase({id, seq}) != 0) return;
      if (client_->Received(id, seq)) {
        stored_[{id, seq}]++;
        client_->Stored(id, seq);
      }
    });
  }

  // one round trip: the client says what it has, the generator serves, the client takes it in
  void Exchange() {
    client_->Service();
    server_->Service(0);
    bus_->HandleFor(0);
    client_->Service();
    server_->Service(0);
  }

  ManualClock clock_;
  std::unique_ptr<Bus> bus_;
  std::unique_ptr<SceneServer> server_;
  std::unique_ptr<SceneClient> client_;
  std::set<std::pair<int32_t, int64_t>> drop_;
  std::map<std::pair<int32_t, int64_t>, int> arrivals_;
  std::map<std::pair<int32_t, int64_t>, int> stored_;
  std::vector<int64_t> regenerated_;
  std::vector<std::string> notices_;
};

SceneClientOptions Client(int32_t window, int64_t max_scenes = 0) {
  SceneClientOptions options;
  options.name = "test-consumer";
  options.window = window;
  options.max_scenes = max_scenes;
  options.reask_after_s = 0;    // ask again at every Service: no waiting in tests
  options.credit_period_s = 0;  // and credit at every Service
  return options;
}

// with no reliable consumer registered the generator is never held back; once one is, it may
// run exactly `window` scenes past what the consumer stored, and storing opens the window.
TEST_F(DeliveryFixture, WindowHoldsTheGenerator) {
  SetUpLink(SceneServerOptions{}, Client(3));
  EXPECT_TRUE(server_->MayPublish(1000));
  Exchange();
  EXPECT_EQ(server_->reliable_consumers(), 1);
  EXPECT_TRUE(server_->MayPublish(2));
  EXPECT_FALSE(server_->MayPublish(3));

  server_->Publish(0, EncodedScene(0, 0));
  bus_->HandleFor(0);
  Exchange();
  EXPECT_EQ(client_->StoredThrough(0), 0);
  EXPECT_TRUE(server_->MayPublish(3));
  EXPECT_FALSE(server_->MayPublish(4));
}

// each header field means one thing: credits and resend requests say their seqs in fields of
// their own (stored_through_seq, seqs) and leave header.seq at -1.
TEST_F(DeliveryFixture, SeqsHaveFieldsOfTheirOwn) {
  SetUpLink(SceneServerOptions{}, Client(8));
  std::vector<credit> credits;
  std::vector<resend_request> requests;
  bus_->Subscribe<credit>(kCreditChannel, [&](const credit& m) { credits.push_back(m); });
  bus_->Subscribe<resend_request>(kResendChannel,
                                  [&](const resend_request& m) { requests.push_back(m); });
  Exchange();
  drop_ = {{0, 1}};
  for (int64_t seq = 0; seq < 3; ++seq) server_->Publish(seq, EncodedScene(0, seq));
  bus_->HandleFor(0);
  Exchange();
  bus_->HandleFor(0);
  Exchange();
  ASSERT_FALSE(credits.empty());
  ASSERT_FALSE(requests.empty());
  for (const credit& m : credits) EXPECT_EQ(m.header.seq, -1);
  for (const resend_request& m : requests) EXPECT_EQ(m.header.seq, -1);
  EXPECT_EQ(requests.front().seqs, std::vector<int64_t>({1}));
  // the last credit to generator 0 (a wildcard one, generator_id -1, says -1)
  int64_t stored_through = -2;
  for (const credit& m : credits) {
    if (m.header.generator_id == 0) stored_through = m.stored_through_seq;
    if (m.header.generator_id == -1) {
      EXPECT_EQ(m.stored_through_seq, -1);
    }
  }
  EXPECT_EQ(stored_through, 2);
  EXPECT_EQ(client_->StoredThrough(0), 2);
}

// a scene lost in the middle is asked for and served from the ring; it is stored once.
TEST_F(DeliveryFixture, GapIsResentFromTheRing) {
  SetUpLink(SceneServerOptions{}, Client(8));
  Exchange();
  drop_ = {{0, 1}};
  for (int64_t seq = 0; seq < 3; ++seq) server_->Publish(seq, EncodedScene(0, seq));
  bus_->HandleFor(0);
  EXPECT_EQ(client_->StoredThrough(0), 0);
  EXPECT_EQ(client_->counters().lost, 1);
  Exchange();
  bus_->HandleFor(0);
  EXPECT_EQ(client_->StoredThrough(0), 2);
  EXPECT_EQ(stored_[std::make_pair(0, int64_t{1})], 1);
  EXPECT_EQ(server_->resent(), 1);
  EXPECT_EQ(server_->regenerated(), 0);
  const DeliveryCounters counters = client_->counters();
  EXPECT_EQ(counters.lost, 0);
  EXPECT_EQ(counters.reasked, 1);
  EXPECT_EQ(counters.stored, 3);
}

// a scene received and not yet stored (a writer's group waiting for its commit) is not missing:
// it is never asked for again, not counted lost, and a second copy of it is a duplicate.
TEST_F(DeliveryFixture, PendingSceneIsNotAskedForAgain) {
  SetUpLink(SceneServerOptions{}, Client(8));
  Exchange();
  drop_ = {{0, 0}, {0, 1}};
  for (int64_t seq = 0; seq < 2; ++seq) server_->Publish(seq, EncodedScene(0, seq));
  bus_->HandleFor(0);
  EXPECT_TRUE(client_->Received(0, 0));
  EXPECT_TRUE(client_->Received(0, 1));
  for (int round = 0; round < 3; ++round) Exchange();
  EXPECT_EQ(server_->resent() + server_->regenerated(), 0);
  EXPECT_EQ(client_->counters().lost, 0);
  EXPECT_EQ(client_->counters().reasked, 0);
  EXPECT_FALSE(client_->Received(0, 1));
  EXPECT_EQ(client_->counters().duplicates, 1);
  client_->Stored(0, 0);
  client_->Stored(0, 1);
  EXPECT_EQ(client_->StoredThrough(0), 1);
}

// a seq older than the ring is regenerated (the callback gets that seq) and stored.
TEST_F(DeliveryFixture, BeyondTheRingIsRegenerated) {
  SceneServerOptions server_options;
  server_options.ring_size = 2;
  SetUpLink(server_options, Client(8));
  Exchange();
  drop_ = {{0, 0}};
  for (int64_t seq = 0; seq < 4; ++seq) server_->Publish(seq, EncodedScene(0, seq));
  bus_->HandleFor(0);
  Exchange();
  bus_->HandleFor(0);
  EXPECT_EQ(regenerated_, std::vector<int64_t>{0});
  EXPECT_EQ(server_->regenerated(), 1);
  EXPECT_EQ(client_->StoredThrough(0), 3);
}

// the last scene lost shows no gap to the consumer; the generator resends it when the credit
// says it was not received a while after publication.
TEST_F(DeliveryFixture, LostTailIsResentByTheGenerator) {
  SceneServerOptions server_options;
  server_options.tail_resend_s = 0.5;
  SetUpLink(server_options, Client(8));
  Exchange();
  drop_ = {{0, 2}};
  for (int64_t seq = 0; seq < 3; ++seq) server_->Publish(seq, EncodedScene(0, seq));
  bus_->HandleFor(0);
  Exchange();
  EXPECT_EQ(client_->StoredThrough(0), 1);
  EXPECT_FALSE(server_->AllStoredThrough(2));
  clock_.Advance(0.4);  // not yet: the tail is resent 0.5 s after publication
  Exchange();
  EXPECT_EQ(client_->StoredThrough(0), 1);
  clock_.Advance(0.2);
  Exchange();
  bus_->HandleFor(0);
  Exchange();
  EXPECT_EQ(client_->StoredThrough(0), 2);
  EXPECT_TRUE(server_->AllStoredThrough(2));
  EXPECT_EQ(client_->counters().reasked, 0);
}

// a scene received twice is stored once and counted as a duplicate, also one restored from an
// earlier run; the generator's resume seq follows the restored state.
TEST_F(DeliveryFixture, DuplicatesAndRestore) {
  SetUpLink(SceneServerOptions{}, Client(8));
  client_->Restore(0, {0, 1, 2, 4});
  EXPECT_EQ(client_->StoredThrough(0), 2);
  EXPECT_FALSE(server_->ResumeSeq().has_value());
  Exchange();
  ASSERT_TRUE(server_->ResumeSeq().has_value());
  EXPECT_EQ(*server_->ResumeSeq(), 3);

  EXPECT_FALSE(client_->Received(0, 1));
  EXPECT_FALSE(client_->Received(0, 4));
  EXPECT_TRUE(client_->Received(0, 3));
  client_->Stored(0, 3);
  EXPECT_EQ(client_->StoredThrough(0), 4);
  const DeliveryCounters counters = client_->counters();
  EXPECT_EQ(counters.received, 3);
  EXPECT_EQ(counters.duplicates, 2);
  EXPECT_EQ(counters.stored, 1);
}

// a consumer that wants N scenes in all never lets a generator publish scene N.
TEST_F(DeliveryFixture, MaxScenesShrinksTheWindow) {
  SetUpLink(SceneServerOptions{}, Client(8, 5));
  Exchange();
  EXPECT_TRUE(server_->MayPublish(4));
  EXPECT_FALSE(server_->MayPublish(5));
  for (int64_t seq = 0; seq < 5; ++seq) server_->Publish(seq, EncodedScene(0, seq));
  bus_->HandleFor(0);
  Exchange();
  EXPECT_EQ(client_->StoredThrough(0), 4);
  EXPECT_FALSE(server_->MayPublish(5));
}

// a consumer that takes seqs from 100 on (one task of a cluster job) counts 0..99 as done: the
// generator started at 100 may publish a window past 99 before it heard a scene, a scene below
// 100 is not stored, a gap above it is asked for, and with 4 scenes wanted seq 104 never comes.
TEST_F(DeliveryFixture, FirstSeqCountsEarlierSeqsAsDone) {
  SceneClientOptions options = Client(3, 4);
  options.first_seq = 100;
  SetUpLink(SceneServerOptions{}, options);
  Exchange();
  ASSERT_EQ(server_->reliable_consumers(), 1);
  EXPECT_TRUE(server_->MayPublish(102));
  EXPECT_FALSE(server_->MayPublish(103));
  ASSERT_TRUE(server_->ResumeSeq().has_value());
  EXPECT_EQ(*server_->ResumeSeq(), 100);
  EXPECT_FALSE(client_->Received(0, 50));

  drop_ = {{0, 101}};
  for (int64_t seq = 100; seq <= 102; ++seq) server_->Publish(seq, EncodedScene(0, seq));
  bus_->HandleFor(0);
  EXPECT_EQ(client_->counters().lost, 1);
  Exchange();
  bus_->HandleFor(0);
  EXPECT_EQ(client_->StoredThrough(0), 102);
  EXPECT_EQ(stored_.count({0, 101}), 1u);
  Exchange();
  server_->Publish(103, EncodedScene(0, 103));
  bus_->HandleFor(0);
  Exchange();
  EXPECT_EQ(client_->StoredThrough(0), 103);
  EXPECT_EQ(client_->counters().stored, 4);
  EXPECT_EQ(client_->counters().lost, 0);
  EXPECT_FALSE(server_->MayPublish(104));
  EXPECT_THROW(
      {
        options.first_seq = -1;
        SceneClient refused(bus_.get(), options);
      },
      std::invalid_argument);
}

// a scene skipped as invalid does not use up the scenes a consumer wants: the generator may still
// publish enough for it to store them all.
TEST_F(DeliveryFixture, SkippedScenesDoNotUseUpMaxScenes) {
  SetUpLink(SceneServerOptions{}, Client(8, 3));
  Exchange();
  EXPECT_TRUE(client_->Received(0, 0));
  client_->Skipped(0, 0);
  EXPECT_TRUE(client_->Received(0, 1));
  client_->Stored(0, 1);
  Exchange();
  EXPECT_EQ(client_->StoredThrough(0), 1);
  EXPECT_TRUE(server_->MayPublish(3));
  EXPECT_FALSE(server_->MayPublish(4));
  // ids out of range are not tracked
  EXPECT_FALSE(client_->Received(-1, 0));
  EXPECT_FALSE(client_->Received(0, -1));
  EXPECT_EQ(client_->counters().received, 2);
}

// requests from a consumer that is not registered, or for seqs beyond its window, are not served:
// a stray request cannot make the generator regenerate its history.
TEST_F(DeliveryFixture, StrayResendRequestsAreNotServed) {
  SetUpLink(SceneServerOptions{}, Client(2));
  drop_ = {{0, 0}, {0, 1}};
  for (int64_t seq = 0; seq < 2; ++seq) server_->Publish(seq, EncodedScene(0, seq));
  resend_request stray{};
  stray.consumer = "nobody";
  stray.num_seqs = 2;
  stray.seqs = {0, 1};
  bus_->Publish(kResendChannel, stray);
  server_->Service(0);
  EXPECT_EQ(server_->resent() + server_->regenerated(), 0);

  Exchange();  // registers test-consumer: stored through -1, window 2
  stray.consumer = "test-consumer";
  stray.seqs = {1, 5};
  bus_->Publish(kResendChannel, stray);
  server_->Service(0);
  // 5 was never published: no SceneClient asks for it, the whole request is refused and counted
  EXPECT_EQ(server_->resent(), 0);
  EXPECT_EQ(server_->bad_messages(), 1);
  stray.num_seqs = 1;
  stray.seqs = {1};
  bus_->Publish(kResendChannel, stray);
  server_->Service(0);
  EXPECT_EQ(server_->resent(), 1);
}

// credits and resend requests that no SceneClient sends are refused and counted, and register
// nobody: windows below 0 or above 10000, seqs out of range, no name; resend requests for more
// than 256 seqs or for seqs out of order.
TEST_F(DeliveryFixture, AbsurdCreditsAndRequestsAreRefused) {
  SetUpLink(SceneServerOptions{}, Client(2));
  server_->Publish(0, EncodedScene(0, 0));
  const auto send_credit = [this](const std::string& name, int64_t stored, int32_t window) {
    credit message{};
    message.header.generator_id = 0;
    message.stored_through_seq = stored;
    message.consumer = name;
    message.window = window;
    message.last_received_seq = -1;
    bus_->Publish(kCreditChannel, message);
    server_->Service(0);
  };
  send_credit("huge-window", -1, 10001);
  send_credit("negative-window", -1, -1);
  send_credit("", -1, 4);
  send_credit("bad-seq", -2, 4);
  send_credit("bad-seq", int64_t{1} << 40, 4);
  EXPECT_EQ(server_->reliable_consumers(), 0);
  EXPECT_EQ(server_->bad_messages(), 5);
  EXPECT_TRUE(server_->MayPublish(1000));

  send_credit("fine", -1, 10000);
  EXPECT_EQ(server_->reliable_consumers(), 1);
  resend_request request{};
  request.header.generator_id = 0;
  request.consumer = "fine";
  request.num_seqs = 300;
  request.seqs.assign(300, 0);
  bus_->Publish(kResendChannel, request);
  request.num_seqs = 2;
  request.seqs = {0, 0};
  bus_->Publish(kResendChannel, request);
  server_->Service(0);
  EXPECT_EQ(server_->bad_messages(), 7);
  EXPECT_EQ(server_->resent() + server_->regenerated(), 0);
  ASSERT_FALSE(notices_.empty());
}

// a consumer that offers no window holds the generator for the consumer timeout, then is no
// longer waited for, and its window-0 credits do not register it again; a window does.
TEST_F(DeliveryFixture, NoWindowHoldsOnlyForTheTimeout) {
  SceneServerOptions server_options;
  server_options.consumer_timeout_s = 0.05;
  SetUpLink(server_options, Client(1));
  const auto send_credit = [this](int32_t window) {
    credit message{};
    message.header.generator_id = 0;
    message.stored_through_seq = -1;
    message.consumer = "closed";
    message.window = window;
    message.last_received_seq = -1;
    bus_->Publish(kCreditChannel, message);
    server_->Service(0);
  };
  send_credit(0);
  EXPECT_FALSE(server_->MayPublish(0));
  clock_.Advance(0.03);
  send_credit(0);
  EXPECT_FALSE(server_->MayPublish(0));
  clock_.Advance(0.04);
  send_credit(0);
  EXPECT_TRUE(server_->MayPublish(0));
  ASSERT_FALSE(notices_.empty());
  EXPECT_NE(notices_.back().find("no window"), std::string::npos) << notices_.back();
  send_credit(0);
  EXPECT_EQ(server_->reliable_consumers(), 0);
  send_credit(3);
  EXPECT_EQ(server_->reliable_consumers(), 1);
  EXPECT_FALSE(server_->MayPublish(3));
}

// a consumer that stops taking scenes (paused: its credits stop) gets no tail resends once it
// has been silent for a second; one that keeps crediting without receiving gets them ever more
// rarely (0.01 s, then 0.02, 0.04, ...), not every tail_resend_s: in 0.3 s, rounds at 0.01, 0.03,
// 0.07 and 0.15 s (the next is due at 0.31), each of the 2 scenes, 8 resends; at a fixed 0.01 s
// it would be 30 rounds.
TEST_F(DeliveryFixture, TailResendsBackOff) {
  SceneServerOptions server_options;
  server_options.tail_resend_s = 0.01;
  server_options.min_resend_interval_s = 0;
  SetUpLink(server_options, Client(4));
  Exchange();
  // the client receives nothing from here on: every copy it is sent is dropped
  drop_ = {{0, 0}, {0, 1}};
  server_->Publish(0, EncodedScene(0, 0));
  server_->Publish(1, EncodedScene(0, 1));
  for (int ms = 0; ms < 300; ++ms) {
    clock_.Advance(0.001);
    client_->Service();
    server_->Service(0);
    drop_ = {{0, 0}, {0, 1}};
  }
  EXPECT_EQ(server_->resent(), 8);
  // paused: no credit for over a second, then no more tail resends at all
  clock_.Advance(1.1);
  const int64_t before = server_->resent();
  for (int round = 0; round < 20; ++round) {
    server_->Service(0);
    clock_.Advance(0.01);
  }
  EXPECT_EQ(server_->resent(), before);
}

// a consumer that credits but receives no copy of what it lacks (a bus that loses them all)
// stalls the run: after stall_timeout_s of resends without progress stalled() names it, never
// before; one that receives again is not stalled, nor one that stopped crediting (paused).
TEST_F(DeliveryFixture, AConsumerThatReceivesNothingStallsTheRun) {
  SceneServerOptions server_options;
  server_options.tail_resend_s = 0.05;
  server_options.min_resend_interval_s = 0;
  server_options.stall_timeout_s = 5;
  server_options.consumer_timeout_s = 100;
  SetUpLink(server_options, Client(4));
  Exchange();
  server_->Publish(0, EncodedScene(0, 0));
  bus_->HandleFor(0);
  Exchange();
  EXPECT_EQ(client_->StoredThrough(0), 0);
  // from here every copy of seq 1 is lost
  server_->Publish(1, EncodedScene(0, 1));
  const auto run_for = [this](double seconds) {
    for (double t = 0; t < seconds; t += 0.05) {
      drop_ = {{0, 1}};
      clock_.Advance(0.05);
      client_->Service();
      server_->Service(0);
      drop_ = {{0, 1}};
      bus_->HandleFor(0);
    }
  };
  run_for(4.5);
  EXPECT_GT(server_->resent(), 2);
  EXPECT_EQ(server_->stalled(), "");
  run_for(1);
  const std::string stalled = server_->stalled();
  EXPECT_NE(stalled.find("test-consumer"), std::string::npos) << stalled;
  EXPECT_NE(stalled.find("from seq 1"), std::string::npos) << stalled;
  // a copy gets through: progress, no longer stalled
  server_->Publish(2, EncodedScene(0, 2));
  bus_->HandleFor(0);
  Exchange();
  EXPECT_EQ(server_->stalled(), "");
  // paused (no credit for over a second): not stalled however long it lasts
  run_for(6);
  EXPECT_NE(server_->stalled(), "");
  clock_.Advance(2);
  EXPECT_EQ(server_->stalled(), "");
}

// a generator's server can go before its bus: its subscriptions end with it, so credits and
// resend requests that still come are handled by no one (no handler into a destroyed server)
TEST_F(DeliveryFixture, ServerEndsBeforeItsBus) {
  SetUpLink(SceneServerOptions{}, Client(2));
  Exchange();
  EXPECT_EQ(bus_->state().handlers(kCreditChannel), 1);
  EXPECT_EQ(bus_->state().handlers(kResendChannel), 1);
  server_.reset();
  EXPECT_EQ(bus_->state().handlers(kCreditChannel), 0);
  EXPECT_EQ(bus_->state().handlers(kResendChannel), 0);
  client_->Service();
  resend_request request{};
  request.header.generator_id = 0;
  request.consumer = "test-consumer";
  request.seqs = {0};
  request.num_seqs = 1;
  bus_->Publish(kResendChannel, request);
  EXPECT_GE(bus_->HandleFor(0), 2);
}

// a consumer that goes silent is dropped after the timeout, with a notice; one that leaves is
// dropped at once; either way the generator is free again.
TEST_F(DeliveryFixture, SilentOrLeavingConsumerIsDropped) {
  SceneServerOptions server_options;
  server_options.consumer_timeout_s = 0.05;
  SetUpLink(server_options, Client(1));
  Exchange();
  EXPECT_FALSE(server_->MayPublish(1));
  clock_.Advance(0.04);
  server_->Service(0);
  EXPECT_FALSE(server_->MayPublish(1));  // 0.04 s of silence: not yet
  clock_.Advance(0.06);
  server_->Service(0);
  EXPECT_TRUE(server_->MayPublish(1));
  ASSERT_FALSE(notices_.empty());
  EXPECT_NE(notices_.back().find("silent"), std::string::npos) << notices_.back();

  Exchange();
  EXPECT_FALSE(server_->MayPublish(1));
  client_->Leave();
  server_->Service(0);
  EXPECT_TRUE(server_->MayPublish(1));
  EXPECT_NE(notices_.back().find("left"), std::string::npos) << notices_.back();
}

// credits of another generator do not hold this one; a consumer keeps two generators' seqs
// apart (the same seq from each is stored twice, once per generator).
TEST_F(DeliveryFixture, GeneratorsAreKeptApart) {
  SceneServerOptions server_options;
  server_options.generator_id = 7;
  SetUpLink(server_options, Client(2));
  Exchange();
  // the consumer has stored nothing of generator 3: it may still publish 0 and 1 ...
  EXPECT_TRUE(client_->Received(3, 0));
  client_->Stored(3, 0);
  EXPECT_TRUE(client_->Received(3, 1));
  client_->Stored(3, 1);
  Exchange();
  // ... and generator 7 is still held to its own window
  EXPECT_TRUE(server_->MayPublish(1));
  EXPECT_FALSE(server_->MayPublish(2));
  server_->Publish(0, EncodedScene(7, 0));
  bus_->HandleFor(0);
  EXPECT_EQ(client_->StoredThrough(7), 0);
  EXPECT_EQ(client_->StoredThrough(3), 1);
}

// the whole protocol over a bus that drops 30 % of what it receives (scenes, credits and resend
// requests alike): every one of 200 scenes is stored exactly once.
TEST_F(DeliveryFixture, EveryoneStoredOnceDespiteLoss) {
  SceneServerOptions server_options;
  server_options.ring_size = 16;
  server_options.tail_resend_s = 0.01;
  server_options.min_resend_interval_s = 0;
  BusOptions lossy;
  lossy.drop_receive_fraction = 0.3;
  lossy.fault_seed = 42;
  SetUpLink(server_options, Client(4), lossy);
  constexpr int64_t kScenes = 200;
  int64_t next = 0;
  // a bound on the rounds, not a timing check: it fails only if delivery stalls
  for (int round = 0;
       round < 100000 && !(next == kScenes && server_->AllStoredThrough(kScenes - 1)); ++round) {
    if (next < kScenes && server_->MayPublish(next)) {
      server_->Publish(next, EncodedScene(0, next));
      ++next;
    }
    Exchange();
    clock_.Advance(0.001);
  }
  ASSERT_EQ(next, kScenes);
  EXPECT_TRUE(server_->AllStoredThrough(kScenes - 1));
  EXPECT_EQ(client_->StoredThrough(0), kScenes - 1);
  EXPECT_EQ(stored_.size(), static_cast<size_t>(kScenes));
  for (const auto& [key, times] : stored_) EXPECT_EQ(times, 1) << "seq " << key.second;
  EXPECT_GT(bus_->state().fault_dropped(), 0);
  EXPECT_GT(server_->resent() + server_->regenerated(), 0);
  EXPECT_EQ(client_->counters().lost, 0);
}

// two consumers that split one stream (seq % 2) each store only their own seqs, never ask for
// the other's (lost or not), and hold the generator back only by what their own shard lacks.
TEST(ShardedDeliveryTest, ShardsSplitTheStream) {
  Bus bus("memq://");
  SceneServerOptions server_options;
  server_options.min_resend_interval_s = 0;
  SceneServer server(
      &bus, server_options, [](int64_t seq) { return EncodedScene(0, seq); },
      [](const std::string&) {});
  std::vector<std::unique_ptr<SceneClient>> clients;
  std::map<int, std::vector<int64_t>> stored;
  for (int shard = 0; shard < 2; ++shard) {
    SceneClientOptions options = Client(2);
    options.name = "worker" + std::to_string(shard);
    options.shard_index = shard;
    options.shard_count = 2;
    clients.push_back(std::make_unique<SceneClient>(&bus, options));
  }
  std::vector<int64_t> asked;
  bus.Subscribe<resend_request>(kResendChannel, [&](const resend_request& request) {
    asked.insert(asked.end(), request.seqs.begin(), request.seqs.end());
  });
  std::set<int64_t> lost = {3};  // seq 3 (shard 1) is lost on its way to both workers
  bus.Subscribe<scene>(kSceneChannel, [&](const scene& message) {
    const int64_t seq = message.header.seq;
    if (lost.count(seq) != 0) return;
    for (int shard = 0; shard < 2; ++shard) {
      if (clients[shard]->Received(0, seq)) {
        stored[shard].push_back(seq);
        clients[shard]->Stored(0, seq);
      }
    }
  });
  const auto exchange = [&] {
    for (auto& client : clients) client->Service();
    server.Service(0);
    bus.HandleFor(0);
  };
  exchange();
  EXPECT_EQ(server.reliable_consumers(), 2);
  // worker 1 counts seq 0 as done from the start: the window of 2 reaches seq 1 for worker 0
  EXPECT_TRUE(server.MayPublish(1));
  EXPECT_FALSE(server.MayPublish(2));
  for (int64_t seq = 0; seq < 5; ++seq) {
    ASSERT_TRUE(server.MayPublish(seq)) << seq;
    server.Publish(seq, EncodedScene(0, seq));
    bus.HandleFor(0);
    exchange();
  }
  EXPECT_EQ(stored[0], (std::vector<int64_t>{0, 2, 4}));
  // worker 1 lacks its seq 3: the generator may not go past 3 + window 2
  EXPECT_FALSE(server.MayPublish(5));
  EXPECT_EQ(clients[1]->counters().lost, 1);
  // worker 1 asked for its seq 3 only; nobody asked for an even seq
  EXPECT_EQ(asked, std::vector<int64_t>{3});
  lost.clear();
  exchange();
  bus.HandleFor(0);
  exchange();
  EXPECT_EQ(stored[1], (std::vector<int64_t>{1, 3}));
  ASSERT_TRUE(server.MayPublish(5));
  server.Publish(5, EncodedScene(0, 5));
  bus.HandleFor(0);
  exchange();
  EXPECT_EQ(stored[1], (std::vector<int64_t>{1, 3, 5}));
  EXPECT_EQ(clients[0]->StoredThrough(0), 5);
  EXPECT_EQ(clients[1]->StoredThrough(0), 6);
  EXPECT_TRUE(server.AllStoredThrough(5));
  for (auto& client : clients) {
    EXPECT_EQ(client->counters().lost, 0);
    EXPECT_EQ(client->counters().received, 3);
  }
  EXPECT_THROW(
      {
        SceneClientOptions options = Client(2);
        options.shard_index = 2;
        options.shard_count = 2;
        SceneClient bad(&bus, options);
      },
      std::invalid_argument);
}

// a consumer given a list of generators credits those by name from the start and sends no
// wildcard credit, so another generator never registers it and is never held back by it.
TEST(ShardedDeliveryTest, GeneratorListSendsNoWildcard) {
  Bus bus("memq://");
  const auto server_for = [&](int32_t id) {
    SceneServerOptions options;
    options.generator_id = id;
    return std::make_unique<SceneServer>(
        &bus, options, [id](int64_t seq) { return EncodedScene(id, seq); },
        [](const std::string&) {});
  };
  auto listed = server_for(3);
  auto other = server_for(5);
  SceneClientOptions options = Client(1);
  options.generator_ids = {3};
  SceneClient client(&bus, options);
  std::set<int32_t> credited;
  bus.Subscribe<credit>(
      kCreditChannel, [&](const credit& message) { credited.insert(message.header.generator_id); });
  client.Service();
  listed->Service(0);
  other->Service(0);
  EXPECT_EQ(credited, std::set<int32_t>{3});
  EXPECT_EQ(listed->reliable_consumers(), 1);
  EXPECT_EQ(other->reliable_consumers(), 0);
  EXPECT_FALSE(listed->MayPublish(1));
  EXPECT_TRUE(other->MayPublish(1000));
  EXPECT_FALSE(client.Received(5, 0));
  EXPECT_TRUE(client.Received(3, 0));
  EXPECT_EQ(client.counters().received, 1);
}

// a learner (join_where_heard) registers with a generator only once it hears it: one that has
// run for a while is taken from the scene heard, with nothing of its history resent and no
// wildcard credit; one heard within its first window of seqs is taken from seq 0
TEST(ShardedDeliveryTest, LearnerJoinsWhereItHears) {
  Bus bus("memq://");
  SceneServerOptions server_options;
  server_options.tail_resend_s = 0;
  SceneServer server(
      &bus, server_options, [](int64_t seq) { return EncodedScene(0, seq); },
      [](const std::string&) {});
  SceneClientOptions options = Client(4);
  options.join_where_heard = true;
  SceneClient learner(&bus, options);
  std::vector<int64_t> stored;
  std::set<int32_t> credited;
  bus.Subscribe<credit>(
      kCreditChannel, [&](const credit& message) { credited.insert(message.header.generator_id); });
  bool listening = false;
  bus.Subscribe<scene>(kSceneChannel, [&](const scene& message) {
    if (!listening) return;
    if (learner.Received(message.header.generator_id, message.header.seq)) {
      stored.push_back(message.header.seq);
      learner.Stored(message.header.generator_id, message.header.seq);
    }
  });
  // the generator runs alone for 20 scenes (the learner is not listening yet)
  learner.Service();
  server.Service(0);
  EXPECT_EQ(server.reliable_consumers(), 0);
  EXPECT_TRUE(credited.empty());
  for (int64_t seq = 0; seq < 20; ++seq) server.Publish(seq, EncodedScene(0, seq));
  bus.HandleFor(0);
  // the learner starts listening, hears seq 20 and joins there
  listening = true;
  server.Publish(20, EncodedScene(0, 20));
  bus.HandleFor(0);
  for (int round = 0; round < 3; ++round) {
    learner.Service();
    server.Service(0);
    bus.HandleFor(0);
  }
  EXPECT_EQ(stored, std::vector<int64_t>{20});
  EXPECT_EQ(learner.StoredThrough(0), 20);
  EXPECT_EQ(server.reliable_consumers(), 1);
  EXPECT_EQ(server.resent() + server.regenerated(), 0);
  EXPECT_EQ(credited, std::set<int32_t>{0});
  EXPECT_TRUE(server.MayPublish(24));
  EXPECT_FALSE(server.MayPublish(25));

  // a generator first heard at seq 2 started with the learner: seqs 0 and 1 are asked for
  SceneClient fresh(&bus, options);
  EXPECT_TRUE(fresh.Received(3, 2));
  fresh.Stored(3, 2);
  EXPECT_EQ(fresh.StoredThrough(3), -1);
  EXPECT_EQ(fresh.counters().lost, 2);
}

// a drop fraction outside [0, 1) is refused with the flag named.
TEST(DropFractionTest, ParsesAndRefuses) {
  EXPECT_DOUBLE_EQ(ParseDropFraction("--fault-drop", "0.1"), 0.1);
  EXPECT_DOUBLE_EQ(ParseDropFraction("--fault-drop", "0"), 0.0);
  for (const char* bad : {"1", "-0.1", "x", "0.1x", ""}) {
    try {
      ParseDropFraction("--fault-drop", bad);
      ADD_FAILURE() << "accepted " << bad;
    } catch (const std::invalid_argument& error) {
      EXPECT_NE(std::string(error.what()).find("--fault-drop"), std::string::npos);
    }
  }
}

// the bus drops close to the fraction asked for, the same messages for the same seed.
TEST(FaultDropTest, FractionAndSeed) {
  const auto dropped = [](uint64_t seed) {
    BusOptions options;
    options.drop_receive_fraction = 0.1;
    options.fault_seed = seed;
    Bus bus("memq://", options);
    std::vector<int64_t> kept;
    bus.Subscribe<credit>(kCreditChannel,
                          [&](const credit& m) { kept.push_back(m.stored_through_seq); });
    for (int64_t i = 0; i < 2000; ++i) {
      credit message{};
      message.stored_through_seq = i;
      bus.Publish(kCreditChannel, message);
      bus.HandleFor(0);
    }
    EXPECT_EQ(bus.state().fault_dropped(), 2000 - static_cast<int64_t>(kept.size()));
    return kept;
  };
  const std::vector<int64_t> a = dropped(1), b = dropped(1), c = dropped(2);
  EXPECT_EQ(a, b);
  EXPECT_NE(a, c);
  EXPECT_NEAR(2000.0 - a.size(), 200.0, 45.0);
}

}  // namespace
}  // namespace stackgen
