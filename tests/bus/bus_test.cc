#include "bus/bus.h"

#include <cstdlib>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <stackgen/header.hpp>
#include <stackgen/status.hpp>

#include "bus/channels.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

status MakeStatus(int64_t seq) {
  status message{};
  message.header.seq = seq;
  message.header.generator_id = 3;
  message.process = "test";
  message.scenes = seq * 2;
  return message;
}

// a typed message published on memq:// arrives decoded, field for field, on its channel only.
TEST(BusTest, MemqRoundTrip) {
  Bus bus("memq://");
  std::vector<status> received;
  bus.Subscribe<status>(kStatusChannel, [&](const status& m) { received.push_back(m); });
  bus.Publish(kStatusChannel, MakeStatus(7));
  bus.Publish("OTHER_CHANNEL", MakeStatus(8));
  bus.HandleFor(0);
  ASSERT_EQ(received.size(), 1u);
  EXPECT_EQ(received[0].header.seq, 7);
  EXPECT_EQ(received[0].header.generator_id, 3);
  EXPECT_EQ(received[0].process, "test");
  EXPECT_EQ(received[0].scenes, 14);
}

// a message of another type on our channel is a decode error that names the channel.
TEST(BusTest, DecodeErrorNamesChannel) {
  Bus bus("memq://");
  bus.Subscribe<status>(kStatusChannel, [](const status&) { FAIL() << "must not decode"; });
  header wrong_type{};
  bus.Publish(kStatusChannel, wrong_type);
  try {
    bus.HandleFor(0);
    FAIL() << "expected a DecodeError";
  } catch (const DecodeError& error) {
    EXPECT_NE(std::string(error.what()).find(kStatusChannel), std::string::npos) << error.what();
  }
}

// with an error callback, bad messages are reported and skipped, later good ones still arrive.
TEST(BusTest, DecodeErrorCallbackSkips) {
  Bus bus("memq://");
  int good = 0;
  std::vector<std::string> errors;
  bus.Subscribe<status>(
      kStatusChannel, [&](const status&) { ++good; }, 16,
      [&](const std::string& text) { errors.push_back(text); });
  bus.Publish(kStatusChannel, header{});
  bus.Publish(kStatusChannel, MakeStatus(1));
  EXPECT_EQ(bus.HandleFor(0), 2);
  EXPECT_EQ(good, 1);
  ASSERT_EQ(errors.size(), 1u);
  EXPECT_NE(errors[0].find("status on channel STACKGEN_STATUS"), std::string::npos) << errors[0];
}

// an exception thrown by a handler reaches the caller of HandleFor, not LCM's C code.
TEST(BusTest, HandlerErrorIsRethrown) {
  Bus bus("memq://");
  bus.Subscribe<status>(kStatusChannel,
                        [](const status&) { throw std::runtime_error("handler failed"); });
  bus.Publish(kStatusChannel, MakeStatus(1));
  EXPECT_THROW(
      {
        try {
          bus.HandleFor(0);
        } catch (const std::runtime_error& error) {
          EXPECT_STREQ(error.what(), "handler failed");
          throw;
        }
      },
      std::runtime_error);
}

// the URL comes from the flag first, then STACKGEN_LCM_URL, then the default.
TEST(BusTest, ResolveLcmUrl) {
  unsetenv("STACKGEN_LCM_URL");
  EXPECT_EQ(ResolveLcmUrl(""), kDefaultLcmUrl);
  setenv("STACKGEN_LCM_URL", "memq://", 1);
  EXPECT_EQ(ResolveLcmUrl(""), "memq://");
  EXPECT_EQ(ResolveLcmUrl("udpm://239.255.76.67:1234?ttl=0"), "udpm://239.255.76.67:1234?ttl=0");
  unsetenv("STACKGEN_LCM_URL");
}

// a udpm URL that does not name a multicast group is refused with the URL in the message.
TEST(BusTest, RejectsNonMulticastAddress) {
  try {
    Bus bus("udpm://10.1.2.3:7667?ttl=0");
    FAIL() << "expected an error";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find("10.1.2.3"), std::string::npos) << error.what();
  }
}

// messages cross real UDP multicast on loopback between two bus instances.
TEST(BusTest, MulticastRoundTrip) {
  const std::string url = testing::FreeMulticastUrl();
  Bus receiver(url);
  Bus sender(url);
  std::vector<int64_t> seqs;
  receiver.Subscribe<status>(kStatusChannel, [&](const status& m) { seqs.push_back(m.header.seq); });
  for (int64_t seq = 0; seq < 5; ++seq) sender.Publish(kStatusChannel, MakeStatus(seq));
  for (int attempt = 0; attempt < 50 && seqs.size() < 5; ++attempt) receiver.HandleFor(100);
  EXPECT_EQ(seqs, (std::vector<int64_t>{0, 1, 2, 3, 4}));
}

}  // namespace
}  // namespace stackgen
