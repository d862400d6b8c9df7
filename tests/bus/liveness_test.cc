#include "bus/liveness.h"

#include <sys/stat.h>

#include <cstdint>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "bus/bus.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

const std::string kKey = "0123456789abcdef0123456789abcdef0123456789abcdef\n";

// one process's key check and liveness check; what it sends waits in `outbox`, sealed
struct Peer {
  explicit Peer(const std::string& key_file, bool require_liveness = true)
      : auth(key_file, require_liveness),
        check(
            &auth,
            [this](const liveness& message) {
              const std::vector<uint8_t> bytes = EncodeMessage(message);
              std::vector<uint8_t> sealed;
              auth.Seal(kLivenessChannel, bytes.data(), bytes.size(), &sealed);
              outbox.push_back(sealed);
            },
            [this](const std::string& line) { warnings.push_back(line); },
            [this] { return ++nonces * 7919; }) {}

  // hands `sealed` (a liveness message of another process) to the check, as a Bus does
  void Hear(const std::vector<uint8_t>& sealed, int64_t now_us) {
    ASSERT_GE(auth.Verify(kLivenessChannel, sealed.data(), sealed.size(), nullptr), 0);
    Trailer trailer;
    ASSERT_TRUE(ReadTrailer(sealed.data(), sealed.size(), &trailer));
    liveness message;
    ASSERT_GE(message.decode(sealed.data(), 0, static_cast<int>(sealed.size() - kAuthTrailerBytes)),
              0);
    check.Handle(message, trailer.sender, trailer.counter, now_us);
  }

  // everything in the outbox, heard by `other` at `now_us`
  void DeliverTo(Peer& other, int64_t now_us) {
    std::vector<std::vector<uint8_t>> sent;
    sent.swap(outbox);
    for (const auto& message : sent) other.Hear(message, now_us);
  }

  MessageAuth auth;
  std::vector<std::vector<uint8_t>> outbox;
  std::vector<std::string> warnings;
  int64_t nonces = 0;
  LivenessCheck check;
};

std::string KeyFile(const testing::ScratchDir& dir) {
  const std::string path = dir.path() + "/bus.key";
  std::ofstream(path) << kKey;
  chmod(path.c_str(), 0600);
  return path;
}

// A writer that starts challenges every process; the generator answers at once and challenges
// back; after one round trip each takes what the other signs from then on, nothing before.
TEST(LivenessCheckTest, OneRoundTripProvesBothWays) {
  const testing::ScratchDir dir("liveness");
  Peer writer(KeyFile(dir)), generator(KeyFile(dir));
  std::vector<uint8_t> early;
  const std::vector<uint8_t> bytes = {1, 2, 3};
  generator.auth.Seal("STACKGEN_SCENE", bytes.data(), bytes.size(), &early);

  writer.check.Start(0);
  EXPECT_FALSE(writer.auth.Live(generator.auth.sender()));
  writer.DeliverTo(generator, 1000);  // the hello: answered, and the writer challenged
  EXPECT_EQ(generator.check.answers(), 1);
  EXPECT_EQ(generator.check.challenges(), 1);
  generator.DeliverTo(writer, 2000);  // the answer, and the challenge: answered
  EXPECT_TRUE(writer.auth.Live(generator.auth.sender()));
  writer.DeliverTo(generator, 3000);
  EXPECT_TRUE(generator.auth.Live(writer.auth.sender()));

  std::vector<uint8_t> later;
  generator.auth.Seal("STACKGEN_SCENE", bytes.data(), bytes.size(), &later);
  EXPECT_EQ(writer.auth.Open("STACKGEN_SCENE", later.data(), later.size(), nullptr), 3);
  EXPECT_EQ(writer.auth.Open("STACKGEN_SCENE", early.data(), early.size(), nullptr), -1);
}

// A challenge heard again (a stranger replays a recorded one, the same sender and counter) is
// answered once, not 100,000 times; fresh challenges of a flood are answered no faster than
// kAnswersPerS (200 in a burst, then 200 a second); a real challenger that was not answered
// asks again in a message of its own and is answered once the rate allows.
TEST(LivenessCheckTest, ChallengesAreAnsweredOnceAndAtABoundedRate) {
  const testing::ScratchDir dir("liveness");
  Peer writer(KeyFile(dir)), generator(KeyFile(dir));
  writer.check.Start(0);
  ASSERT_EQ(writer.outbox.size(), 1u);
  const std::vector<uint8_t> recorded = writer.outbox.front();
  for (int i = 0; i < 100000; ++i) generator.Hear(recorded, 1000 + i);
  EXPECT_EQ(generator.check.answers(), 1);
  EXPECT_EQ(generator.check.repeats(), 99999);

  // 1000 fresh challenges within 10 ms: the burst is answered, the rest not
  Peer flood(KeyFile(dir));
  for (int i = 0; i < 1000; ++i) {
    flood.check.Start(200000 + i * 10);
    flood.DeliverTo(generator, 200000 + i * 10);
  }
  const int64_t answered = generator.check.answers() - 1;
  EXPECT_GE(answered, 200);
  EXPECT_LE(answered, 203);
  EXPECT_EQ(generator.check.throttled(), 1000 - answered);
  // a second later the rate allows one more: a new challenge is answered
  flood.check.Start(1300000);
  flood.DeliverTo(generator, 1300000);
  EXPECT_EQ(generator.check.answers(), answered + 2);
}

// A recording cannot answer: a writer that starts while a log of an earlier run plays back
// challenges its senders, hears the recorded answers (to another run's nonces) and takes
// nothing; once they have sent for 2 s without answering, their messages count as replayed,
// and they are challenged at most every 0.25 s; at 10 s without an answer one warning says so
// (a live sender across a very lossy link can take longer than 2 s to be heard answering).
TEST(LivenessCheckTest, ARecordingNeverAnswers) {
  const testing::ScratchDir dir("liveness");
  Peer old_writer(KeyFile(dir)), generator(KeyFile(dir));
  old_writer.check.Start(0);
  old_writer.DeliverTo(generator, 0);
  const std::vector<std::vector<uint8_t>> recorded = generator.outbox;  // its answer, recorded
  ASSERT_FALSE(recorded.empty());

  Peer writer(KeyFile(dir));
  writer.check.Start(10'000'000);
  for (const auto& message : recorded) writer.Hear(message, 10'000'100);
  EXPECT_FALSE(writer.auth.Live(generator.auth.sender()));

  // the recording's scenes keep coming, 100 ms apart, for 3 s
  for (int64_t t = 10'100'000; t <= 13'100'000; t += 100'000) {
    writer.check.Unanswered(generator.auth.sender(), "STACKGEN_SCENE", t);
  }
  EXPECT_FALSE(writer.auth.Live(generator.auth.sender()));
  // the hello, then a challenge at once and again whenever over 0.25 s passed (every 0.3 s at
  // these 0.1 s steps): 11
  EXPECT_EQ(writer.check.challenges(), 1 + 11);
  // those after 2 s without an answer are counted: 2.1 s .. 3.0 s after the first
  EXPECT_EQ(writer.auth.counters().replayed, 11);
  EXPECT_TRUE(writer.warnings.empty()) << writer.warnings[0];
  for (int64_t t = 13'200'000; t <= 20'100'000; t += 100'000) {
    writer.check.Unanswered(generator.auth.sender(), "STACKGEN_SCENE", t);
  }
  ASSERT_EQ(writer.warnings.size(), 1u);
  EXPECT_NE(writer.warnings[0].find("has not answered the liveness check of the bus key for 10 s"),
            std::string::npos)
      << writer.warnings[0];
  EXPECT_NE(writer.warnings[0].find("--replay"), std::string::npos) << writer.warnings[0];
}

// Challenges are answered only by the process they name (or every process for 0), and only
// when the challenger named is the one that signed it; an answer counts only from the process
// asked, with the nonce asked.
TEST(LivenessCheckTest, OnlyTheRightAnswerCounts) {
  const testing::ScratchDir dir("liveness");
  Peer a(KeyFile(dir)), b(KeyFile(dir)), c(KeyFile(dir));
  // a challenges b; c hears it and does not answer
  a.check.Unanswered(b.auth.sender(), "STACKGEN_SCENE", 0);
  const std::vector<std::vector<uint8_t>> challenge = a.outbox;
  a.DeliverTo(c, 1);
  EXPECT_TRUE(c.outbox.empty());
  for (const auto& message : challenge) b.Hear(message, 2);
  // b's answer heard by c (not its challenge) proves nothing to c
  const std::vector<std::vector<uint8_t>> answer = b.outbox;
  b.DeliverTo(c, 3);
  EXPECT_FALSE(c.auth.Live(b.auth.sender()));
  for (const auto& message : answer) a.Hear(message, 4);
  EXPECT_TRUE(a.auth.Live(b.auth.sender()));
}

// Without liveness (a consumer told it reads a replay) every verified sender is taken at once.
TEST(LivenessCheckTest, AReplayConsumerTakesEveryone) {
  const testing::ScratchDir dir("liveness");
  Peer replay(KeyFile(dir), false), generator(KeyFile(dir));
  EXPECT_TRUE(replay.auth.Live(generator.auth.sender()));
  std::vector<uint8_t> scene;
  const std::vector<uint8_t> bytes = {9};
  generator.auth.Seal("STACKGEN_SCENE", bytes.data(), bytes.size(), &scene);
  EXPECT_EQ(replay.auth.Open("STACKGEN_SCENE", scene.data(), scene.size(), nullptr), 1);
}

}  // namespace
}  // namespace stackgen
