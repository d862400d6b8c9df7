#include "bus/auth.h"

#include <sys/stat.h>

#include <cstdint>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <stackgen/status.hpp>

#include "bus/bus.h"
#include "bus/log.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

// a key file of `text` with `mode` in `dir`
std::string KeyFile(const testing::ScratchDir& dir, const std::string& name,
                    const std::string& text, mode_t mode = 0600) {
  const std::string path = dir.path() + "/" + name;
  std::ofstream(path) << text;
  chmod(path.c_str(), mode);
  return path;
}

const std::string kKey = "0123456789abcdef0123456789abcdef0123456789abcdef\n";
const std::string kOtherKey = "fedcba9876543210fedcba9876543210fedcba9876543210\n";

std::vector<uint8_t> Bytes(const std::string& text) { return {text.begin(), text.end()}; }

// what Open says of `sealed` on `channel`, and why
struct Opened {
  int64_t size;
  std::string why;
};
Opened Open(MessageAuth& auth, const std::string& channel, const std::vector<uint8_t>& sealed) {
  Opened opened{};
  opened.size = auth.Open(channel, sealed.data(), sealed.size(), &opened.why);
  return opened;
}

// A sealed message opens under the same key, once: a copy sent again is a replay; altered bytes,
// another channel, another key (named by its key id) and no trailer are refused, each counted
// under its reason.
TEST(MessageAuthTest, ForgedAlteredAndReplayedAreRefused) {
  const testing::ScratchDir dir("auth");
  MessageAuth sender(KeyFile(dir, "a.key", kKey), true);
  MessageAuth receiver(KeyFile(dir, "b.key", kKey), false);
  MessageAuth stranger(KeyFile(dir, "c.key", kOtherKey), true);
  ASSERT_TRUE(sender.keyed());
  const std::vector<uint8_t> payload = Bytes("a credit, say");
  std::vector<uint8_t> sealed;
  sender.Seal("STACKGEN_CREDIT", payload.data(), payload.size(), &sealed);
  ASSERT_EQ(sealed.size(), payload.size() + kAuthTrailerBytes);

  EXPECT_EQ(Open(receiver, "STACKGEN_CREDIT", sealed).size, static_cast<int64_t>(payload.size()));
  const Opened again = Open(receiver, "STACKGEN_CREDIT", sealed);
  EXPECT_EQ(again.size, -1);
  EXPECT_NE(again.why.find("received before"), std::string::npos) << again.why;

  std::vector<uint8_t> altered = sealed;
  altered[3] ^= 0x01;
  EXPECT_EQ(Open(receiver, "STACKGEN_CREDIT", altered).size, -1);
  std::vector<uint8_t> moved;
  sender.Seal("STACKGEN_CREDIT", payload.data(), payload.size(), &moved);
  const Opened elsewhere = Open(receiver, "STACKGEN_RESEND", moved);
  EXPECT_EQ(elsewhere.size, -1);
  EXPECT_NE(elsewhere.why.find("STACKGEN_RESEND"), std::string::npos) << elsewhere.why;
  std::vector<uint8_t> foreign;
  stranger.Seal("STACKGEN_CREDIT", payload.data(), payload.size(), &foreign);
  const Opened forged = Open(receiver, "STACKGEN_CREDIT", foreign);
  EXPECT_EQ(forged.size, -1);
  EXPECT_NE(forged.why.find("signed with another bus key (key id " + KeyIdText(stranger.key_id())),
            std::string::npos)
      << forged.why;
  EXPECT_NE(forged.why.find("has key id " + KeyIdText(receiver.key_id())), std::string::npos)
      << forged.why;
  const Opened bare = Open(receiver, "STACKGEN_CREDIT", payload);
  EXPECT_EQ(bare.size, -1);
  EXPECT_NE(bare.why.find("not signed"), std::string::npos) << bare.why;

  const AuthCounters counted = receiver.counters();
  EXPECT_EQ(counted.replayed, 1);
  EXPECT_EQ(counted.forged, 3);
  EXPECT_EQ(counted.unsigned_messages, 1);
  EXPECT_EQ(counted.total(), 5);
  EXPECT_EQ(receiver.messages(), 6);
}

// Messages of one sender may arrive out of order within the replay window (1024 counters), but
// each counter opens once, and one older than the window never.
TEST(MessageAuthTest, ReplayWindow) {
  const testing::ScratchDir dir("auth");
  const std::string key = KeyFile(dir, "a.key", kKey);
  MessageAuth sender(key, true);
  MessageAuth receiver(key, false);
  const std::vector<uint8_t> payload = Bytes("x");
  std::vector<std::vector<uint8_t>> sealed(1100);
  for (auto& message : sealed) sender.Seal("C", payload.data(), payload.size(), &message);
  EXPECT_EQ(Open(receiver, "C", sealed[5]).size, 1);
  EXPECT_EQ(Open(receiver, "C", sealed[3]).size, 1);  // late, not seen: taken
  EXPECT_EQ(Open(receiver, "C", sealed[3]).size, -1);
  EXPECT_EQ(Open(receiver, "C", sealed[1099]).size, 1);
  EXPECT_EQ(Open(receiver, "C", sealed[4]).size, -1);  // 1095 counters back: beyond the window
  EXPECT_EQ(Open(receiver, "C", sealed[1000]).size, 1);
}

// With liveness, a sender's messages are taken only once it has answered, and only those it
// signed after its first answer: a recording of it (older messages) is refused whatever its age;
// a process's own messages need no answer, and a log (no liveness) takes them all.
TEST(MessageAuthTest, LivenessTakesOnlyWhatFollowsTheAnswer) {
  const testing::ScratchDir dir("auth");
  const std::string key = KeyFile(dir, "a.key", kKey);
  MessageAuth sender(key, true);
  MessageAuth live(key, true);
  MessageAuth log(key, false);
  const std::vector<uint8_t> payload = Bytes("scene");
  std::vector<std::vector<uint8_t>> sealed(5);
  for (auto& message : sealed) sender.Seal("S", payload.data(), payload.size(), &message);
  EXPECT_FALSE(live.Live(sender.sender()));
  const Opened unanswered = Open(live, "S", sealed[0]);
  EXPECT_EQ(unanswered.size, -1);
  EXPECT_NE(unanswered.why.find("has not answered"), std::string::npos) << unanswered.why;
  live.Proven(sender.sender(), 3);  // it answered in its message 3
  EXPECT_TRUE(live.Live(sender.sender()));
  const Opened before = Open(live, "S", sealed[1]);  // counter 2: signed before the answer
  EXPECT_EQ(before.size, -1);
  EXPECT_NE(before.why.find("before it answered"), std::string::npos) << before.why;
  EXPECT_EQ(Open(live, "S", sealed[3]).size, 5);  // counter 4
  live.Proven(sender.sender(), 6);  // a later answer (to a challenge in flight) moves nothing
  EXPECT_EQ(Open(live, "S", sealed[4]).size, 5);
  EXPECT_EQ(live.counters().replayed, 2);
  for (const auto& message : sealed) EXPECT_EQ(Open(log, "S", message).size, 5);
  std::vector<uint8_t> own;
  live.Seal("S", payload.data(), payload.size(), &own);
  EXPECT_EQ(Open(live, "S", own).size, 5);
}

// A message is bound to the bus it was signed for: on another group or port (a relay between
// two runs of one key) a live receiver refuses it as relayed, naming both buses, and so does the
// key evidence, without blaming a forgery; a log reader and a consumer told that it reads a
// replay take it (a recording may be played onto any bus). Without the bus in the trailer a
// relayed message is taken.
TEST(MessageAuthTest, AMessageIsBoundToItsBus) {
  const testing::ScratchDir dir("auth");
  const std::string key = KeyFile(dir, "a.key", kKey);
  const uint64_t bus_a = BusTag("udpm://239.255.76.67:7000?ttl=0");
  const uint64_t bus_b = BusTag("udpm://239.255.76.67:7001");
  ASSERT_NE(bus_a, bus_b);
  EXPECT_EQ(BusTagText(bus_a), "239.255.76.67:7000");
  EXPECT_EQ(BusTag("file:///x.lcmlog"), 0u);
  MessageAuth sender(key, true, bus_a);
  MessageAuth here(key, true, bus_a);
  MessageAuth there(key, true, bus_b);
  MessageAuth log(key, false);
  MessageAuth replay(key, false, bus_b);
  const std::vector<uint8_t> payload = Bytes("scene");
  std::vector<uint8_t> sealed;
  sender.Seal("S", payload.data(), payload.size(), &sealed);
  EXPECT_EQ(here.Verify("S", sealed.data(), sealed.size(), nullptr), 5);
  std::string why;
  EXPECT_EQ(there.Verify("S", sealed.data(), sealed.size(), &why), -1);
  EXPECT_NE(why.find("signed for another bus (239.255.76.67:7000; this one is "
                     "239.255.76.67:7001): relayed"),
            std::string::npos)
      << why;
  EXPECT_EQ(there.counters().relayed, 1);
  EXPECT_EQ(there.counters().forged, 0);
  EXPECT_EQ(log.Verify("S", sealed.data(), sealed.size(), nullptr), 5);
  EXPECT_EQ(replay.Verify("S", sealed.data(), sealed.size(), nullptr), 5);
  KeyEvidence evidence;
  evidence.Note(there, sealed.data(), sealed.size(), false);
  const std::string line = evidence.Mismatch(there, "the scenes");
  EXPECT_NE(line.find("for another bus (group and port): relayed"), std::string::npos) << line;
  EXPECT_NE(RefusedSummary(there.counters()).find("1 relayed from another bus"),
            std::string::npos);
}

// One key has one key id on every host, another key another; an open process has none.
TEST(MessageAuthTest, KeyIdsTellKeysApart) {
  const testing::ScratchDir dir("auth");
  MessageAuth a(KeyFile(dir, "a.key", kKey), true);
  MessageAuth same(KeyFile(dir, "same.key", kKey), true);
  MessageAuth other(KeyFile(dir, "b.key", kOtherKey), true);
  MessageAuth open("", true);
  EXPECT_EQ(a.key_id(), same.key_id());
  EXPECT_NE(a.key_id(), other.key_id());
  EXPECT_NE(a.key_id(), 0u);
  EXPECT_EQ(open.key_id(), 0u);
  EXPECT_NE(a.sender(), same.sender());
  EXPECT_EQ(KeyIdText(0x0123456789abcdefULL), "0123456789abcdef");
}

// What a process heard tells it that its peers use another key, none, or (open) one, in one
// line naming both key ids; a single message it could take clears it.
TEST(MessageAuthTest, KeyEvidenceNamesTheMismatch) {
  const testing::ScratchDir dir("auth");
  MessageAuth ours(KeyFile(dir, "a.key", kKey), false);
  MessageAuth theirs(KeyFile(dir, "b.key", kOtherKey), false);
  MessageAuth open("", false);
  const std::vector<uint8_t> payload = Bytes("scene");
  std::vector<uint8_t> foreign, own;
  theirs.Seal("S", payload.data(), payload.size(), &foreign);
  ours.Seal("S", payload.data(), payload.size(), &own);

  KeyEvidence other_key;
  other_key.Note(ours, foreign.data(), foreign.size(), false);
  const std::string line = other_key.Mismatch(ours, "the scenes");
  EXPECT_NE(line.find("signed with another bus key (key id " + KeyIdText(theirs.key_id())),
            std::string::npos)
      << line;
  EXPECT_NE(line.find(KeyIdText(ours.key_id())), std::string::npos) << line;
  EXPECT_EQ(line.find('\n'), std::string::npos);
  other_key.Note(ours, own.data(), own.size(), true);
  EXPECT_EQ(other_key.Mismatch(ours, "the scenes"), "");

  KeyEvidence no_key;
  no_key.Note(ours, payload.data(), payload.size(), false);
  EXPECT_NE(no_key.Mismatch(ours, "the scenes").find("not signed"), std::string::npos);

  // altered messages of this key, with an unsigned one beside: they blame no other key id (no
  // "another bus key (key id 0000000000000000)")
  std::vector<uint8_t> altered = own;
  altered[0] ^= 1;
  KeyEvidence forged;
  forged.Note(ours, altered.data(), altered.size(), false);
  forged.Note(ours, altered.data(), altered.size(), false);
  forged.Note(ours, payload.data(), payload.size(), false);
  const std::string forged_line = forged.Mismatch(ours, "the scenes");
  EXPECT_NE(forged_line.find("but fail its check: forged, or altered"), std::string::npos)
      << forged_line;
  EXPECT_EQ(forged_line.find("0000000000000000"), std::string::npos) << forged_line;
  KeyEvidence signed_for_open;
  signed_for_open.Note(open, own.data(), own.size(), true);
  EXPECT_NE(signed_for_open.Mismatch(open, "the scenes").find("--open-bus"), std::string::npos);
  EXPECT_EQ(KeyEvidence{}.Mismatch(ours, "the scenes"), "");
}

// Without a key nothing is sealed or refused, and a trailer is cut off unchecked, so a process
// with an open bus still reads what keyed processes send.
TEST(MessageAuthTest, NoKeyPassesEverything) {
  const testing::ScratchDir dir("auth");
  MessageAuth sender(KeyFile(dir, "a.key", kKey), true);
  MessageAuth keyless("", true);
  EXPECT_FALSE(keyless.keyed());
  const std::vector<uint8_t> payload = Bytes("scene bytes");
  std::vector<uint8_t> sealed;
  sender.Seal("C", payload.data(), payload.size(), &sealed);
  EXPECT_EQ(Open(keyless, "C", sealed).size, static_cast<int64_t>(payload.size()));
  EXPECT_EQ(Open(keyless, "C", sealed).size, static_cast<int64_t>(payload.size()));
  EXPECT_EQ(Open(keyless, "C", payload).size, static_cast<int64_t>(payload.size()));
  std::vector<uint8_t> plain;
  keyless.Seal("C", payload.data(), payload.size(), &plain);
  EXPECT_EQ(plain, payload);
  EXPECT_EQ(keyless.counters().total(), 0);
}

// The key is on by default: with no flag and no $STACKGEN_BUS_KEY_FILE a process uses this
// user's key at $XDG_CONFIG_HOME/stackgen/bus.key, made once (mode 600, in a folder of mode
// 700), and every later process reads the same one.
TEST(MessageAuthTest, TheDefaultKeyIsMadeOnFirstUse) {
  const testing::ScratchDir dir("auth");
  const testing::ScopedEnv no_key("STACKGEN_BUS_KEY_FILE", nullptr);
  const testing::ScopedEnv config("XDG_CONFIG_HOME", (dir.path() + "/config").c_str());
  const std::string path = dir.path() + "/config/stackgen/bus.key";
  EXPECT_EQ(DefaultBusKeyFile(), path);
  EXPECT_EQ(ResolveBusKeyFile(""), path);
  struct stat info {};
  ASSERT_EQ(stat(path.c_str(), &info), 0);
  EXPECT_EQ(info.st_mode & 0777, 0600u);
  ASSERT_EQ(stat((dir.path() + "/config/stackgen").c_str(), &info), 0);
  EXPECT_EQ(info.st_mode & 0777, 0700u);
  const std::string key = testing::ReadFile(path);
  EXPECT_EQ(key.size(), 45u);  // 32 bytes in base64 and a newline
  EXPECT_EQ(ResolveBusKeyFile(""), path);
  EXPECT_EQ(testing::ReadFile(path), key);
  EXPECT_FALSE(MakeBusKeyFile(path));
  MessageAuth first(path, true), second(ResolveBusKeyFile(""), true);
  EXPECT_EQ(first.key_id(), second.key_id());
  // the flag and the environment come first
  EXPECT_EQ(ResolveBusKeyFile("/elsewhere.key"), "/elsewhere.key");
  const testing::ScopedEnv from_env("STACKGEN_BUS_KEY_FILE", "/env.key");
  EXPECT_EQ(ResolveBusKeyFile(""), "/env.key");
}

// A key file that cannot serve is refused with one line naming it: missing, a folder, a FIFO,
// too short, readable by other users.
TEST(MessageAuthTest, BadKeyFilesAreOneLine) {
  const testing::ScratchDir dir("auth");
  const auto error_of = [](const std::string& path) -> std::string {
    try {
      MessageAuth auth(path, true);
    } catch (const std::runtime_error& error) {
      return error.what();
    }
    return "";
  };
  const std::string missing = dir.path() + "/missing.key";
  EXPECT_NE(error_of(missing).find("cannot open bus key file " + missing), std::string::npos)
      << error_of(missing);
  EXPECT_NE(error_of(dir.path()).find("is not a regular file"), std::string::npos);
  // a FIFO is refused at once (opening one waits for a writer unless told not to)
  const std::string fifo = dir.path() + "/fifo.key";
  ASSERT_EQ(mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_NE(error_of(fifo).find("is not a regular file"), std::string::npos) << error_of(fifo);
  const std::string short_key = KeyFile(dir, "short.key", "abc\n");
  EXPECT_NE(error_of(short_key).find("holds 3 bytes; a key needs at least 32"), std::string::npos)
      << error_of(short_key);
  const std::string shared = KeyFile(dir, "shared.key", kKey, 0644);
  EXPECT_NE(error_of(shared).find("can be read or written by other users (mode 0644)"),
            std::string::npos)
      << error_of(shared);
  for (const std::string& path : {missing, short_key, shared}) {
    EXPECT_EQ(error_of(path).find('\n'), std::string::npos);
  }
  EXPECT_EQ(error_of(KeyFile(dir, "group.key", kKey, 0640)), "");
}

// On a bus, processes with the same key hear each other; a bus with another key or none is
// refused and counted in its status counters, and the refused never reach a handler.
TEST(BusAuthTest, OnlyTheKeyHolderIsHeard) {
  const testing::ScratchDir dir("auth");
  BusOptions keyed;
  keyed.key_file = KeyFile(dir, "a.key", kKey);
  Bus bus("memq://", keyed);
  EXPECT_TRUE(bus.state().keyed());
  std::vector<std::string> heard;
  bus.Subscribe<status>("STATUS", [&](const status& message) { heard.push_back(message.name); });
  status message{};
  message.name = "friend";
  bus.Publish("STATUS", message);
  EXPECT_EQ(bus.HandleFor(0), 1);
  EXPECT_EQ(heard, std::vector<std::string>{"friend"});
  // memq:// is one process's bus: messages of another Bus cannot reach it, so the stranger's
  // bytes are handed over as a log would hold them
  const std::string log_path = dir.path() + "/mixed.lcmlog";
  {
    LogAppender friendly(log_path, keyed.key_file);
    LogAppender foreign(log_path, KeyFile(dir, "b.key", kOtherKey));
    LogAppender bare(log_path, "");
    const std::vector<uint8_t> bytes = EncodeMessage(message);
    friendly.AppendBytes("STATUS", bytes.data(), bytes.size(), 1);
    foreign.AppendBytes("STATUS", bytes.data(), bytes.size(), 2);
    bare.AppendBytes("STATUS", bytes.data(), bytes.size(), 3);
  }
  Bus replay("file://" + log_path + "?speed=0", keyed);
  int replayed = 0;
  replay.Subscribe<status>("STATUS", [&](const status&) { ++replayed; });
  while (!replay.state().log_ended()) replay.HandleFor(100);
  EXPECT_EQ(replayed, 1);
  EXPECT_EQ(replay.state().auth_counters().forged, 1);
  EXPECT_EQ(replay.state().auth_counters().unsigned_messages, 1);

  // a process with an open bus reads all three (trailers cut off, nothing checked)
  BusOptions none;
  none.open_bus = true;
  Bus unkeyed("file://" + log_path + "?speed=0", none);
  EXPECT_FALSE(unkeyed.state().keyed());
  int read = 0;
  unkeyed.Subscribe<status>("STATUS", [&](const status&) { ++read; });
  while (!unkeyed.state().log_ended()) unkeyed.HandleFor(100);
  EXPECT_EQ(read, 3);
}

}  // namespace
}  // namespace stackgen
