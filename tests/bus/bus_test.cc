#include "bus/bus.h"

#include <poll.h>

#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <stackgen/header.hpp>
#include <stackgen/status.hpp>

#include "bus/channels.h"
#include "tests/support/lcm_wire.h"
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
// a Subscription made to end when dropped removes its handler then (the channel's other
// handlers stay); a plain one keeps its handler; a handler may end its own subscription while it
// runs; a Subscription may outlive its bus
TEST(BusTest, SubscriptionsThatEndWhenDropped) {
  auto bus = std::make_unique<Bus>("memq://");
  std::vector<std::string> calls;
  const auto publish_and_handle = [&] {
    calls.clear();
    bus->Publish(kStatusChannel, MakeStatus(1));
    bus->HandleFor(0);
  };
  bus->Subscribe<status>(kStatusChannel, [&](const status&) { calls.push_back("kept"); });
  {
    Subscription ending =
        bus->Subscribe<status>(kStatusChannel, [&](const status&) { calls.push_back("scoped"); })
            .EndWhenDropped();
    EXPECT_TRUE(ending.active());
    publish_and_handle();
    EXPECT_EQ(calls, (std::vector<std::string>{"kept", "scoped"}));
  }
  publish_and_handle();
  EXPECT_EQ(calls, std::vector<std::string>{"kept"});

  Subscription self;
  const std::string label = "once";  // read through the handler's captures after its Reset
  self = bus->Subscribe<status>(kStatusChannel,
                                [&calls, &self, label](const status&) {
                                  self.Reset();
                                  calls.push_back(label);
                                })
             .EndWhenDropped();
  EXPECT_EQ(bus->state().handlers(kStatusChannel), 2);
  publish_and_handle();
  EXPECT_EQ(calls, (std::vector<std::string>{"kept", "once"}));
  EXPECT_FALSE(self.active());
  EXPECT_EQ(bus->state().handlers(kStatusChannel), 1);
  publish_and_handle();
  EXPECT_EQ(calls, std::vector<std::string>{"kept"});

  Subscription outliving =
      bus->Subscribe<status>(kStatusChannel, [](const status&) {}).EndWhenDropped();
  bus.reset();
  EXPECT_FALSE(outliving.active());
  outliving.Reset();  // nothing to remove, nothing touched
}

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

// messages cross real UDP multicast on loopback between two bus instances, once the receiver
// has heard the sender answer the liveness check of the bus key (a sender's first messages,
// before that, are dropped: each is published until it arrives)
TEST(BusTest, MulticastRoundTrip) {
  const std::string url = testing::FreeMulticastUrl();
  Bus receiver(url);
  Bus sender(url);
  std::vector<int64_t> seqs;
  receiver.Subscribe<status>(kStatusChannel,
                             [&](const status& m) { seqs.push_back(m.header.seq); });
  for (int64_t seq = 0; seq < 5; ++seq) {
    for (int attempt = 0; attempt < 50 && static_cast<int64_t>(seqs.size()) <= seq; ++attempt) {
      sender.Publish(kStatusChannel, MakeStatus(seq));
      receiver.HandleFor(100);
    }
  }
  EXPECT_EQ(seqs, (std::vector<int64_t>{0, 1, 2, 3, 4}));
}

// Two open buses hear each other's every message at once: no key, no liveness check.
TEST(BusTest, OpenBusesNeedNoAnswer) {
  const std::string url = testing::FreeMulticastUrl();
  BusOptions open;
  open.open_bus = true;
  Bus receiver(url, open);
  Bus sender(url, open);
  EXPECT_FALSE(sender.state().keyed());
  std::vector<int64_t> seqs;
  receiver.Subscribe<status>(kStatusChannel,
                             [&](const status& m) { seqs.push_back(m.header.seq); });
  for (int64_t seq = 0; seq < 5; ++seq) sender.Publish(kStatusChannel, MakeStatus(seq));
  for (int attempt = 0; attempt < 50 && seqs.size() < 5; ++attempt) receiver.HandleFor(100);
  EXPECT_EQ(seqs, (std::vector<int64_t>{0, 1, 2, 3, 4}));
}

// a plain socket on the group of `url` that reads whatever datagrams arrive
class RawMulticastListener {
 public:
  explicit RawMulticastListener(const std::string& url) {
    const UdpmAddress address = ParseUdpmUrl(url);
    fd_ = socket(AF_INET, SOCK_DGRAM, 0);
    const int on = 1;
    setsockopt(fd_, SOL_SOCKET, SO_REUSEADDR, &on, sizeof(on));
    const int buffer = 4 << 20;  // the default one holds fewer than three 64 KB datagrams
    setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &buffer, sizeof(buffer));
    sockaddr_in bound{};
    bound.sin_family = AF_INET;
    bound.sin_port = htons(address.port);
    bound.sin_addr.s_addr = htonl(address.group);
    bind(fd_, reinterpret_cast<sockaddr*>(&bound), sizeof(bound));
    ip_mreq membership{};
    membership.imr_multiaddr.s_addr = htonl(address.group);
    membership.imr_interface.s_addr = htonl(INADDR_ANY);
    setsockopt(fd_, IPPROTO_IP, IP_ADD_MEMBERSHIP, &membership, sizeof(membership));
  }
  ~RawMulticastListener() { close(fd_); }

  // the datagrams that arrive within `timeout_ms` of each other
  std::vector<std::vector<uint8_t>> Read(int timeout_ms) {
    std::vector<std::vector<uint8_t>> datagrams;
    pollfd fd = {fd_, POLLIN, 0};
    while (poll(&fd, 1, timeout_ms) > 0) {
      std::vector<uint8_t> datagram(65536);
      const ssize_t size = recv(fd_, datagram.data(), datagram.size(), 0);
      if (size < 0) break;
      datagram.resize(static_cast<size_t>(size));
      datagrams.push_back(datagram);
    }
    return datagrams;
  }

 private:
  int fd_ = -1;
};

// What a Bus sends on one host for a short and a fragmented message is byte for byte the wire
// format the tests write by hand (tests/support/lcm_wire.h), with a message counter from 0: what
// liblcm 1.3.1 sent when the Bus sent through it (this test passed then as now), so lcm-spy,
// lcm-logger and lcm-logplayer read it.
TEST(BusTest, ABusSendsTheWireFormatOfTheTests) {
  const std::string url = testing::FreeMulticastUrl();
  RawMulticastListener listener(url);
  BusOptions open;  // no trailer, no liveness check: only the two messages go out
  open.open_bus = true;
  Bus sender(url, open);
  std::vector<uint8_t> small = {1, 2, 3, 4, 5};
  std::vector<uint8_t> large(150000);
  for (size_t i = 0; i < large.size(); ++i) large[i] = static_cast<uint8_t>(i * 7);
  sender.PublishEncoded(kCreditChannel, small);
  sender.PublishEncoded(kSceneChannel, large);
  std::vector<std::vector<uint8_t>> expected = testing::LcmDatagrams(kCreditChannel, small, 0);
  for (const auto& datagram : testing::LcmDatagrams(kSceneChannel, large, 1)) {
    expected.push_back(datagram);
  }
  EXPECT_EQ(listener.Read(500), expected);
}

// The two datagrams that make liblcm 1.3.1 write 4 GB past a buffer (lcm#628) reach a bus that
// listens on their channel, which then takes the next scene as usual (with liblcm's receiver
// this test dies of SIGSEGV); the datagram is counted as malformed.
TEST(BusTest, TwoDatagramsOfLcm628DoNotCrashAReceiver) {
  const std::string url = testing::FreeMulticastUrl();
  Bus receiver(url);
  std::vector<int64_t> seqs;
  receiver.Subscribe<status>(kSceneChannel, [&](const status& m) { seqs.push_back(m.header.seq); });
  const testing::RawMulticastSender stranger(url);
  std::vector<uint8_t> first = testing::LcmFragmentHeader(7, 5000, 0, 0, 2);
  const std::string channel = kSceneChannel;
  first.insert(first.end(), channel.begin(), channel.end());
  first.push_back(0);
  first.resize(first.size() + 1000, 0);
  std::vector<uint8_t> second = testing::LcmFragmentHeader(7, 5000, 0xFFFFFF00, 1, 2);
  second.resize(second.size() + 1000, 'A');
  ASSERT_TRUE(stranger.Send(first));
  ASSERT_TRUE(stranger.Send(second));
  Bus sender(url);
  for (int attempt = 0; attempt < 50 && seqs.empty(); ++attempt) {
    sender.Publish(kSceneChannel, MakeStatus(42));
    receiver.HandleFor(100);
  }
  EXPECT_EQ(seqs, std::vector<int64_t>{42});
  EXPECT_EQ(receiver.state().receive_counters().malformed, 1);
}

// A keyed consumer that reads scenes but watches the config channel too (Bus::WatchKeys) hears
// its generator's key in the config announced before the first scene, so a stranger's unsigned
// messages on the scene channel meanwhile are not all it heard; one that does not watch the
// config channel has heard only those, and KeyMismatch says that its peers do not sign, once the
// mismatch is as old as asked (on the bus's clock).
TEST(BusTest, WatchedChannelsShowTheGeneratorsKeyBeforeItsFirstScene) {
  const std::string url = testing::FreeMulticastUrl();
  const std::vector<std::string> generator_channels = {kSceneChannel, kConfigChannel};
  ManualClock clock;
  BusOptions on_clock;
  on_clock.clock = &clock;
  Bus watching(url);
  Bus blind(url, on_clock);
  for (Bus* consumer : {&watching, &blind}) {
    consumer->Subscribe<status>(kSceneChannel, [](const status&) {});
  }
  watching.state().WatchKeys(generator_channels);
  ASSERT_TRUE(watching.state().keyed());
  BusOptions open;
  open.open_bus = true;
  Bus stranger(url, open);
  Bus generator(url);
  for (int round = 0; round < 50; ++round) {
    generator.Publish(kConfigChannel, MakeStatus(-1));
    stranger.Publish(kSceneChannel, MakeStatus(round));
    watching.HandleFor(20);
    blind.HandleFor(20);
    if (round >= 10 && watching.state().auth_counters().unsigned_messages >= 5 &&
        blind.state().auth_counters().unsigned_messages >= 5) {
      break;
    }
  }
  EXPECT_GE(blind.state().auth_counters().unsigned_messages, 5);
  EXPECT_NE(blind.state().KeyMismatch(generator_channels, 0).find("are not signed"),
            std::string::npos);
  EXPECT_EQ(blind.state().KeyMismatch(generator_channels, 2), "");
  clock.Advance(2);
  EXPECT_NE(blind.state().KeyMismatch(generator_channels, 2).find("are not signed"),
            std::string::npos);
  EXPECT_GE(watching.state().auth_counters().unsigned_messages, 5);
  EXPECT_EQ(watching.state().KeyMismatch(generator_channels, 0), "");
}

}  // namespace
}  // namespace stackgen
