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
Opened Open(MessageAuth& auth, const std::string& channel, const std::vector<uint8_t>& sealed,
            int64_t now_us = UnixMicros()) {
  Opened opened{};
  opened.size = auth.Open(channel, sealed.data(), sealed.size(), now_us, &opened.why);
  return opened;
}

// A sealed message opens under the same key, once: a copy sent again is a replay; altered bytes,
// another channel, another key and no trailer are refused, each counted under its reason.
TEST(MessageAuthTest, ForgedAlteredAndReplayedAreRefused) {
  const testing::ScratchDir dir("auth");
  MessageAuth sender(KeyFile(dir, "a.key", kKey), true);
  MessageAuth receiver(KeyFile(dir, "b.key", kKey), true);
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
  EXPECT_NE(forged.why.find("MAC does not match"), std::string::npos) << forged.why;
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
// each counter opens once, one older than the window never, and on a live bus neither does one
// stamped over a minute away; a log (not live) has no age limit.
TEST(MessageAuthTest, ReplayWindowAndAge) {
  const testing::ScratchDir dir("auth");
  const std::string key = KeyFile(dir, "a.key", kKey);
  MessageAuth sender(key, true);
  MessageAuth live(key, true);
  const std::vector<uint8_t> payload = Bytes("x");
  std::vector<std::vector<uint8_t>> sealed(1100);
  for (auto& message : sealed) sender.Seal("C", payload.data(), payload.size(), &message);
  EXPECT_EQ(Open(live, "C", sealed[5]).size, 1);
  EXPECT_EQ(Open(live, "C", sealed[3]).size, 1);  // late, not seen: taken
  EXPECT_EQ(Open(live, "C", sealed[3]).size, -1);
  EXPECT_EQ(Open(live, "C", sealed[1099]).size, 1);
  EXPECT_EQ(Open(live, "C", sealed[4]).size, -1);  // 1095 counters back: beyond the window
  EXPECT_EQ(Open(live, "C", sealed[1000]).size, 1);

  std::vector<uint8_t> fresh;
  sender.Seal("C", payload.data(), payload.size(), &fresh);
  const Opened late = Open(live, "C", fresh, UnixMicros() + 61'000'000);
  EXPECT_EQ(late.size, -1);
  EXPECT_NE(late.why.find("s ago"), std::string::npos) << late.why;
  MessageAuth log(key, false);
  EXPECT_EQ(Open(log, "C", fresh, UnixMicros() + 3'600'000'000).size, 1);
}

// Without a key nothing is sealed or refused, and a trailer is cut off unchecked, so a process
// with no key still reads what keyed processes send.
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

// A key file that cannot serve is refused with one line naming it: missing, a folder, too short,
// readable by other users.
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
  EXPECT_TRUE(bus.keyed());
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
  while (!replay.log_ended()) replay.HandleFor(100);
  EXPECT_EQ(replayed, 1);
  EXPECT_EQ(replay.auth_counters().forged, 1);
  EXPECT_EQ(replay.auth_counters().unsigned_messages, 1);

  // a process with no key reads all three (trailers cut off, nothing checked)
  BusOptions none;
  none.key_file = "";
  const testing::ScopedEnv no_key("STACKGEN_BUS_KEY_FILE", nullptr);
  Bus unkeyed("file://" + log_path + "?speed=0", none);
  EXPECT_FALSE(unkeyed.keyed());
  int read = 0;
  unkeyed.Subscribe<status>("STATUS", [&](const status&) { ++read; });
  while (!unkeyed.log_ended()) unkeyed.HandleFor(100);
  EXPECT_EQ(read, 3);
}

}  // namespace
}  // namespace stackgen
