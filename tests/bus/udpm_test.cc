#include "bus/udpm.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/lcm_wire.h"
#include "tests/support/process.h"

namespace stackgen {
namespace {

using testing::LcmDatagrams;
using testing::LcmFragmentHeader;

const std::string kChannel = "STACKGEN_SCENE";

std::vector<uint8_t> Payload(size_t size, uint32_t seed) {
  std::mt19937 random(seed);
  std::vector<uint8_t> bytes(size);
  for (uint8_t& byte : bytes) byte = static_cast<uint8_t>(random());
  return bytes;
}

// a reassembler that wants kChannel only
class Reassembler {
 public:
  explicit Reassembler(const UdpmLimits& limits = {})
      : reassembler_(limits, [](const std::string& channel) { return channel == kChannel; }) {}

  // the messages `datagrams` from `sender` complete, as payloads
  std::vector<std::vector<uint8_t>> Add(const std::vector<std::vector<uint8_t>>& datagrams,
                                        uint64_t sender = 1) {
    std::vector<std::vector<uint8_t>> messages;
    for (const std::vector<uint8_t>& datagram : datagrams) {
      UdpmMessage message;
      if (reassembler_.Add(sender, datagram.data(), datagram.size(), &message)) {
        EXPECT_EQ(message.channel, kChannel);
        messages.emplace_back(message.data.get(), message.data.get() + message.size);
      }
    }
    return messages;
  }

  UdpmReassembler& get() { return reassembler_; }

 private:
  UdpmReassembler reassembler_;
};

// Messages as liblcm sends them come out whole: one datagram, or fragments of 65487 bytes with
// the channel in the first; a channel nobody wants allocates nothing.
TEST(UdpmReassemblerTest, LiblcmMessagesComeOutWhole) {
  Reassembler reassembler;
  const std::vector<uint8_t> small = Payload(1000, 1);
  const std::vector<uint8_t> large = Payload(150000, 2);
  ASSERT_EQ(LcmDatagrams(kChannel, large, 8).size(), 3u);
  EXPECT_EQ(reassembler.Add(LcmDatagrams(kChannel, small, 7)),
            std::vector<std::vector<uint8_t>>{small});
  EXPECT_EQ(reassembler.Add(LcmDatagrams(kChannel, large, 8)),
            std::vector<std::vector<uint8_t>>{large});
  EXPECT_TRUE(reassembler.Add(LcmDatagrams("STACKGEN_OTHER", large, 9)).empty());
  EXPECT_EQ(reassembler.get().partials(), 0);
  EXPECT_EQ(reassembler.get().counters().messages, 2);
  EXPECT_EQ(reassembler.get().counters().malformed, 0);
  EXPECT_EQ(reassembler.get().counters().datagrams, 7);
}

// The two datagrams that make liblcm 1.3.1 write about 4 GB past a buffer (a fragment offset
// that wraps a 32-bit sum, lcm#628) are one malformed message here, and the sender's next
// message is taken as usual.
TEST(UdpmReassemblerTest, TheWrappingOffsetOfLcm628IsDropped) {
  Reassembler reassembler;
  std::vector<uint8_t> first = LcmFragmentHeader(7, 5000, 0, 0, 2);
  first.insert(first.end(), kChannel.begin(), kChannel.end());
  first.push_back(0);
  first.resize(first.size() + 1000, 0);
  std::vector<uint8_t> second = LcmFragmentHeader(7, 5000, 0xFFFFFF00, 1, 2);
  second.resize(second.size() + 1000, 'A');
  EXPECT_TRUE(reassembler.Add({first, second}).empty());
  EXPECT_EQ(reassembler.get().counters().malformed, 1);
  EXPECT_EQ(reassembler.get().partials(), 0);
  EXPECT_EQ(reassembler.get().partial_bytes(), 0u);
  const std::vector<uint8_t> large = Payload(100000, 3);
  EXPECT_EQ(reassembler.Add(LcmDatagrams(kChannel, large, 8)),
            std::vector<std::vector<uint8_t>>{large});
}

// Each field a sender chooses that does not fit its message is dropped and counted, and the
// message it belongs to with it; none of them yields a message.
TEST(UdpmReassemblerTest, EveryInconsistentDatagramIsDropped) {
  const std::vector<uint8_t> large = Payload(150000, 4);
  const std::vector<std::vector<uint8_t>> good = LcmDatagrams(kChannel, large, 5);
  // a copy of `datagram` with bytes [at, at + n) set to `value` (big-endian)
  const auto with = [](std::vector<uint8_t> datagram, size_t at, int n, uint64_t value) {
    for (int i = n - 1; i >= 0; --i, value >>= 8) datagram[at + i] = static_cast<uint8_t>(value);
    return datagram;
  };
  std::vector<uint8_t> no_nul = LcmDatagrams(kChannel, {1, 2}, 1)[0];
  no_nul.resize(8 + kChannel.size());
  std::vector<uint8_t> long_channel = {'L', 'C', '0', '2', 0, 0, 0, 1};
  long_channel.insert(long_channel.end(), 64, 'X');
  long_channel.push_back(0);
  std::vector<uint8_t> empty_channel = {'L', 'C', '0', '2', 0, 0, 0, 1, 0, 42};
  std::vector<uint8_t> gap = good[1];
  gap.pop_back();  // one byte short: the fragments no longer cover the message

  const std::vector<std::pair<std::string, std::vector<std::vector<uint8_t>>>> cases = {
      {"too short for a header", {{'L', 'C', '0'}}},
      {"another magic", {with(good[0], 0, 4, 0x4c433034)}},
      {"a channel without its NUL", {no_nul}},
      {"a channel of 64 bytes", {long_channel}},
      {"an empty channel", {empty_channel}},
      {"a fragment header cut short",
       {std::vector<uint8_t>(good[0].begin(), good[0].begin() + 19)}},
      {"message size 0", {with(good[0], 8, 4, 0)}},
      {"message size above the limit", {with(good[0], 8, 4, 0xFFFFFFFF)}},
      {"fragment count 0", {with(good[0], 18, 2, 0)}},
      {"fragment number beyond the count", {good[0], with(good[1], 16, 2, 3)}},
      {"fragment 0 not at offset 0", {with(good[0], 12, 4, 10)}},
      {"fragment 0 again, of another channel", {good[0], LcmDatagrams("STACKGEN_X", large, 5)[0]}},
      {"a fragment again, of another length",
       {good[0], good[1], std::vector<uint8_t>(good[1].begin(), good[1].end() - 1)}},
      {"a fragment naming another message size", {good[0], with(good[1], 8, 4, 150001)}},
      {"overlapping fragments", {good[0], with(good[1], 12, 4, 65000)}},
      {"a fragment past the end", {good[0], with(good[2], 12, 4, 149990)}},
      {"a gap", {good[0], gap, good[2]}},
      {"an empty fragment", {good[0], std::vector<uint8_t>(good[1].begin(), good[1].begin() + 20)}},
  };
  for (const auto& [what, datagrams] : cases) {
    Reassembler reassembler;
    EXPECT_TRUE(reassembler.Add(datagrams).empty()) << what;
    EXPECT_EQ(reassembler.get().counters().malformed, 1) << what;
    EXPECT_EQ(reassembler.get().counters().messages, 0) << what;
    // the good message from the start still comes through after it
    EXPECT_EQ(reassembler.Add(good).size(), 1u) << what;
  }
}

// Reassembly holds the fragments heard, counted with their bookkeeping, within its bounds: the
// least recent message gives way to a new one past max_partials, a sender's next message ends
// its last, and a message that could not fit whole is never begun.
TEST(UdpmReassemblerTest, ReassemblyMemoryIsBounded) {
  UdpmLimits limits;
  limits.max_partial_bytes = 450000;
  limits.max_partials = 3;
  Reassembler reassembler(limits);
  const std::vector<uint8_t> large = Payload(200000, 6);
  const std::vector<std::vector<uint8_t>> datagrams = LcmDatagrams(kChannel, large, 1);
  ASSERT_EQ(datagrams.size(), 4u);
  for (uint64_t sender = 1; sender <= 10; ++sender) {
    EXPECT_TRUE(reassembler.Add({datagrams[0]}, sender).empty());
    EXPECT_LE(reassembler.get().partial_bytes(), limits.max_partial_bytes);
    EXPECT_LE(reassembler.get().partials(), 3);
    // the fragment heard and its bookkeeping, not the 200000 bytes the message claims
    EXPECT_LT(reassembler.get().partial_bytes(), 3 * (datagrams[0].size() + 1024));
  }
  EXPECT_EQ(reassembler.get().counters().abandoned, 7);
  // sender 10 starts another message: its first one is given up
  const std::vector<std::vector<uint8_t>> next = LcmDatagrams(kChannel, large, 2);
  EXPECT_TRUE(reassembler.Add({next[0]}, 10).empty());
  EXPECT_EQ(reassembler.get().counters().abandoned, 8);
  // sender 9's message is whole once its fragments come (the bytes make the least recent, 8,
  // give way)
  EXPECT_EQ(reassembler.Add({datagrams[1], datagrams[2], datagrams[3]}, 9),
            std::vector<std::vector<uint8_t>>{large});
  EXPECT_LE(reassembler.get().partial_bytes(), limits.max_partial_bytes);
  // a message larger than reassembly may hold is never begun
  UdpmLimits tight;
  tight.max_partial_bytes = 150000;
  Reassembler small(tight);
  EXPECT_TRUE(small.Add(datagrams).empty());
  EXPECT_EQ(small.get().partial_bytes(), 0u);
  EXPECT_EQ(small.get().partials(), 0);
  EXPECT_EQ(small.get().counters().malformed, 1);  // its fragment 0; the others have no message
}

// What a stranger's fragments can pin: claims of messages cost nothing until their bytes come,
// 200,000 one-byte fragments from 64 senders stay within the bound (counted with their
// bookkeeping they would hold 26 MB) while a real message completes among them, and what is left is given up partial_timeout_s after its last fragment, its memory
// freed. Holding the bytes claimed at once fails the first check.
TEST(UdpmReassemblerTest, AFragmentFloodIsBoundedAndExpires) {
  UdpmLimits limits;
  limits.max_partial_bytes = 4 << 20;
  limits.partial_timeout_s = 2;
  Reassembler reassembler(limits);
  UdpmReassembler& r = reassembler.get();
  const auto fragment = [](uint32_t seqno, uint32_t size, uint32_t offset, uint16_t number,
                           uint16_t count, size_t bytes) {
    std::vector<uint8_t> datagram = LcmFragmentHeader(seqno, size, offset, number, count);
    if (number == 0) {
      datagram.insert(datagram.end(), kChannel.begin(), kChannel.end());
      datagram.push_back(0);
    }
    datagram.resize(datagram.size() + bytes, 0x5A);
    return datagram;
  };
  UdpmMessage message;
  // 64 claims of 2 MB in 4000 fragments, one byte heard each
  for (uint64_t sender = 100; sender < 164; ++sender) {
    const std::vector<uint8_t> claim = fragment(1, 2000000, 0, 0, 4000, 1);
    EXPECT_FALSE(r.Add(sender, claim.data(), claim.size(), 0.0, &message));
  }
  EXPECT_EQ(r.partials(), 64);
  EXPECT_LT(r.partial_bytes(), size_t{128} * 1024);  // of 128 MB claimed
  // one-byte fragments, spread over the senders, with a real message in the middle
  const std::vector<uint8_t> real = Payload(150000, 9);
  const std::vector<std::vector<uint8_t>> real_datagrams = LcmDatagrams(kChannel, real, 5);
  int whole = 0;
  for (int i = 0; i < 200000; ++i) {
    const uint64_t sender = 100 + i % 64;
    const uint16_t number = static_cast<uint16_t>(1 + i / 64);
    const std::vector<uint8_t> tiny = fragment(1, 2000000, number, number, 4000, 1);
    const double now_s = i * 1e-5;
    r.Add(sender, tiny.data(), tiny.size(), now_s, &message);
    if (i == 100000) {
      for (const auto& datagram : real_datagrams) {
        if (r.Add(7, datagram.data(), datagram.size(), now_s, &message)) {
          ++whole;
          EXPECT_EQ(std::vector<uint8_t>(message.data.get(), message.data.get() + message.size),
                    real);
        }
      }
    }
    ASSERT_LE(r.partial_bytes(), limits.max_partial_bytes);
    ASSERT_LE(r.partials(), limits.max_partials);
  }
  EXPECT_EQ(whole, 1);
  EXPECT_GT(r.partials(), 0);
  // nothing more comes: 2 s after the last fragment (at 2 s) all is given up and freed
  r.Expire(3.9);
  EXPECT_GT(r.partials(), 0);
  r.Expire(4.1);
  EXPECT_EQ(r.partials(), 0);
  EXPECT_EQ(r.partial_bytes(), 0u);
  // a claim beyond what reassembly may hold is never begun
  const std::vector<uint8_t> huge = fragment(2, 200000000, 0, 0, 4000, 100);
  EXPECT_FALSE(r.Add(200, huge.data(), huge.size(), 5.0, &message));
  EXPECT_EQ(r.partials(), 0);
}

// 50,000 mutations of real datagrams (bits flipped, headers rewritten, cut, grown, fragments
// shuffled between 4 senders; fixed seed) never leave reassembly beyond its bounds, and every
// message that comes out is as long as its fragments said; the clean message gets through after.
TEST(UdpmReassemblerTest, MutatedDatagramsStayWithinBounds) {
  UdpmLimits limits;
  limits.max_message_bytes = 1 << 20;
  limits.max_partial_bytes = 2 << 20;
  limits.max_partials = 8;
  UdpmReassembler reassembler(limits, [](const std::string& channel) {
    return channel == kChannel || channel == "STACKGEN_CREDIT";
  });
  std::vector<std::vector<uint8_t>> pool;
  for (const size_t size : {size_t{300}, size_t{70000}, size_t{200000}}) {
    for (const auto& datagram : LcmDatagrams(kChannel, Payload(size, 7), 11)) {
      pool.push_back(datagram);
    }
  }
  std::mt19937_64 random(20261126);
  int64_t out = 0;
  for (int i = 0; i < 50000; ++i) {
    std::vector<uint8_t> datagram = pool[random() % pool.size()];
    switch (random() % 6) {
      case 0:  // bits flipped
        for (int flip = 0; flip < 1 + static_cast<int>(random() % 8); ++flip) {
          datagram[random() % datagram.size()] ^= static_cast<uint8_t>(1u << (random() % 8));
        }
        break;
      case 1:  // a header field rewritten: seqno, size, offset, number or count
        for (size_t at = 4 + 4 * (random() % 4); at < 20 && at < datagram.size(); ++at) {
          datagram[at] = static_cast<uint8_t>(random());
          if (random() % 2 == 0) break;
        }
        break;
      case 2:  // cut
        datagram.resize(random() % (datagram.size() + 1));
        break;
      case 3:  // grown
        datagram.resize(std::min<size_t>(65535, datagram.size() + 1 + random() % 4096),
                        static_cast<uint8_t>(random()));
        break;
      default:  // as sent, but maybe out of order or from another sender
        break;
    }
    UdpmMessage message;
    if (reassembler.Add(random() % 4, datagram.data(), datagram.size(), &message)) {
      ++out;
      ASSERT_LE(message.size, limits.max_message_bytes);
    }
    ASSERT_LE(reassembler.partial_bytes(), limits.max_partial_bytes);
    ASSERT_LE(reassembler.partials(), limits.max_partials);
  }
  const UdpmCounters counters = reassembler.counters();
  std::printf("50000 mutated datagrams: %lld messages out, %lld malformed, %lld abandoned\n",
              static_cast<long long>(out), static_cast<long long>(counters.malformed),
              static_cast<long long>(counters.abandoned));
  EXPECT_GT(counters.malformed, 3000);
  const std::vector<uint8_t> clean = Payload(200000, 8);
  int whole = 0;
  for (const auto& datagram : LcmDatagrams(kChannel, clean, 99)) {
    UdpmMessage message;
    if (reassembler.Add(5, datagram.data(), datagram.size(), &message)) {
      ++whole;
      EXPECT_EQ(std::vector<uint8_t>(message.data.get(), message.data.get() + message.size), clean);
    }
  }
  EXPECT_EQ(whole, 1);
}

// A fragment heard again at its place (a repair that crossed the first copy) is a repeat: dropped
// and counted, and the message completes with the bytes that came (liblcm counted it again and
// completed early); a late copy after the message completed begins nothing.
TEST(UdpmReassemblerTest, RepeatedFragmentsAreDroppedAndTheMessageCompletes) {
  const std::vector<uint8_t> large = Payload(150000, 4);
  const std::vector<std::vector<uint8_t>> good = LcmDatagrams(kChannel, large, 5);
  ASSERT_EQ(good.size(), 3u);
  Reassembler reassembler;
  EXPECT_TRUE(reassembler.Add({good[0], good[1], good[1], good[0]}).empty());
  EXPECT_EQ(reassembler.Add({good[2]}), std::vector<std::vector<uint8_t>>{large});
  EXPECT_TRUE(reassembler.Add({good[1], good[0]}).empty());
  EXPECT_EQ(reassembler.get().counters().repeats, 4);
  EXPECT_EQ(reassembler.get().counters().malformed, 0);
  EXPECT_EQ(reassembler.get().partials(), 0);
}

// Messages of one sender are reassembled side by side (a repair of one goes on while the next
// arrives), at most max_partials_per_sender of them: its least recent gives way.
TEST(UdpmReassemblerTest, ASenderHasABoundedNumberOfMessagesInReassembly) {
  UdpmLimits limits;
  limits.max_partials_per_sender = 2;
  Reassembler reassembler(limits);
  const std::vector<uint8_t> a = Payload(150000, 1), b = Payload(150000, 2),
                             c = Payload(150000, 3);
  const auto da = LcmDatagrams(kChannel, a, 1), db = LcmDatagrams(kChannel, b, 2),
             dc = LcmDatagrams(kChannel, c, 3);
  EXPECT_TRUE(reassembler.Add({da[0], db[0], da[1], db[1]}).empty());
  EXPECT_EQ(reassembler.get().partials(), 2);
  EXPECT_EQ(reassembler.Add({da[2]}), std::vector<std::vector<uint8_t>>{a});
  EXPECT_TRUE(reassembler.Add({dc[0], dc[1]}).empty());
  EXPECT_TRUE(reassembler.Add({dc[0]}, 2).empty());  // another sender: not counted against it
  EXPECT_EQ(reassembler.get().partials(), 3);
  // a third message of sender 1: b (heard from least recently) gives way
  const std::vector<uint8_t> d = Payload(150000, 4);
  const auto dd = LcmDatagrams(kChannel, d, 4);
  EXPECT_TRUE(reassembler.Add({dd[0]}).empty());
  EXPECT_EQ(reassembler.get().counters().abandoned, 1);
  EXPECT_TRUE(reassembler.Add({db[2]}).empty());
  EXPECT_EQ(reassembler.Add({dc[2], dd[1], dd[2]}), (std::vector<std::vector<uint8_t>>{c, d}));
}

// A message that lacks fragments and hears nothing for repair_after_s asks for exactly those
// (from the first missing one, as a bitmap), again after each quiet spell, at most
// max_repair_asks times in a row; fragments that come reset the count and complete it.
TEST(UdpmReassemblerTest, AMessageMissingFragmentsAsksForThem) {
  const std::vector<uint8_t> payload = Payload(20000, 6);
  // fragments of 1000 bytes: a sender with a small MTU
  std::vector<std::vector<uint8_t>> datagrams;
  const size_t total = kChannel.size() + 1 + payload.size();
  const uint16_t count = static_cast<uint16_t>((total + 999) / 1000);
  for (uint16_t number = 0; number < count; ++number) {
    const size_t start = size_t{number} * 1000, stop = std::min(start + 1000, total);
    const size_t begin = number == 0 ? 0 : start - kChannel.size() - 1;
    std::vector<uint8_t> datagram = testing::LcmFragmentHeader(
        9, static_cast<uint32_t>(payload.size()), static_cast<uint32_t>(begin), number, count);
    if (number == 0) {
      datagram.insert(datagram.end(), kChannel.begin(), kChannel.end());
      datagram.push_back(0);
    }
    datagram.insert(datagram.end(), payload.begin() + static_cast<std::ptrdiff_t>(begin),
                    payload.begin() + static_cast<std::ptrdiff_t>(stop - kChannel.size() - 1));
    datagrams.push_back(datagram);
  }
  ASSERT_EQ(count, 21);
  UdpmLimits limits;
  limits.repair_after_s = 0.05;
  limits.max_repair_asks = 3;
  std::vector<UdpmRepair> asks;
  UdpmReassembler reassembler(
      limits, [](const std::string& channel) { return channel == kChannel; },
      [&asks](const UdpmRepair& ask) {
        asks.push_back(ask);
        return true;
      });
  UdpmMessage message;
  for (const uint16_t number : {0, 1, 2, 4, 5, 6, 7, 8, 10, 20}) {
    ASSERT_FALSE(reassembler.Add(77, datagrams[number].data(), datagrams[number].size(), 100.0,
                                 &message));
  }
  reassembler.Expire(100.04);
  EXPECT_TRUE(asks.empty());
  reassembler.Expire(100.06);
  ASSERT_EQ(asks.size(), 1u);
  EXPECT_EQ(asks[0].sender, 77u);
  EXPECT_EQ(asks[0].seqno, 9u);
  EXPECT_EQ(asks[0].size, payload.size());
  EXPECT_EQ(asks[0].fragments, count);
  EXPECT_EQ(asks[0].first, 3u);
  // fragments 3, 9, 11..19 missing: bits 0, 6, 8..16 from 3
  EXPECT_EQ(asks[0].missing, (std::vector<uint8_t>{0x41, 0xFF, 0x01}));
  EXPECT_NEAR(reassembler.NextDue(100.06), 0.05, 1e-9);
  // quiet: asked again, up to three times in a row, then only the timeout is due
  reassembler.Expire(100.12);
  reassembler.Expire(100.18);
  reassembler.Expire(100.24);
  EXPECT_EQ(asks.size(), 3u);
  // what was asked for comes (from the sender's repair): the asks may start again, and it completes
  for (const uint16_t number : {3, 9, 11, 12, 13, 14, 15, 16, 17, 18}) {
    ASSERT_FALSE(reassembler.Add(77, datagrams[number].data(), datagrams[number].size(), 100.3,
                                 &message));
  }
  reassembler.Expire(100.36);
  ASSERT_EQ(asks.size(), 4u);
  EXPECT_EQ(asks[3].first, 19u);
  EXPECT_EQ(asks[3].missing, std::vector<uint8_t>{0x01});
  ASSERT_TRUE(reassembler.Add(77, datagrams[19].data(), datagrams[19].size(), 100.4, &message));
  EXPECT_EQ(std::vector<uint8_t>(message.data.get(), message.data.get() + message.size), payload);
  EXPECT_EQ(reassembler.counters().repaired, 1);
  EXPECT_EQ(reassembler.counters().repair_asks, 4);
  EXPECT_LT(reassembler.NextDue(100.4), 0);
}

// URLs: the group, port, receive buffer, ttl and mtu are read; what is not a multicast URL is
// one line.
TEST(UdpmUrlTest, ParsesGroupPortAndBuffer) {
  const UdpmAddress address =
      ParseUdpmUrl("udpm://239.255.76.67:7811?ttl=1&recv_buf_size=4096&mtu=9000");
  EXPECT_EQ(address.group, 0xEFFF4C43u);
  EXPECT_EQ(address.port, 7811);
  EXPECT_EQ(address.recv_buf_size, 4096);
  EXPECT_EQ(address.ttl, 1);
  EXPECT_EQ(address.mtu, 9000);
  EXPECT_EQ(ParseUdpmUrl("udpm://239.255.76.67").port, 7667);
  EXPECT_EQ(ParseUdpmUrl("udpm://239.255.76.67").ttl, 0);
  EXPECT_EQ(ParseUdpmUrl("udpm://239.255.76.67").mtu, 0);
  for (const std::string bad :
       {"udpm://10.0.0.1:7667", "udpm://239.255.76.67:0", "udpm://239.255.76.67:x",
        "udpm://239.255.76.67:1?recv_buf_size=-1", "udpm://239.255.76.67:1?ttl=256",
        "udpm://239.255.76.67:1?mtu=500", "udpm://239.255.76.67:1?mtu=1500x",
        "udpm://239.255.76.67:1?tll=1", "memq://"}) {
    EXPECT_THROW(ParseUdpmUrl(bad), std::runtime_error) << bad;
  }
}

// joins the group of `url` and reads its datagrams as they come, with their sender
class RawMulticastReceiver {
 public:
  explicit RawMulticastReceiver(const UdpmAddress& address) {
    fd_ = socket(AF_INET, SOCK_DGRAM, 0);
    const int on = 1, buffer = 8 << 20;
    setsockopt(fd_, SOL_SOCKET, SO_REUSEADDR, &on, sizeof(on));
    setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &buffer, sizeof(buffer));
    sockaddr_in bound{};
    bound.sin_family = AF_INET;
    bound.sin_addr.s_addr = htonl(address.group);
    bound.sin_port = htons(address.port);
    EXPECT_EQ(bind(fd_, reinterpret_cast<const sockaddr*>(&bound), sizeof(bound)), 0);
    ip_mreq membership{};
    membership.imr_multiaddr = bound.sin_addr;
    membership.imr_interface.s_addr = htonl(INADDR_ANY);
    EXPECT_EQ(setsockopt(fd_, IPPROTO_IP, IP_ADD_MEMBERSHIP, &membership, sizeof(membership)), 0);
  }
  ~RawMulticastReceiver() { close(fd_); }

  // the next datagram within `timeout_ms`; false if none came
  bool Next(int timeout_ms, std::vector<uint8_t>* datagram, uint64_t* sender) {
    pollfd fd = {fd_, POLLIN, 0};
    if (poll(&fd, 1, timeout_ms) <= 0) return false;
    datagram->resize(65536);
    sockaddr_in from{};
    socklen_t length = sizeof(from);
    const ssize_t size = recvfrom(fd_, datagram->data(), datagram->size(), 0,
                                  reinterpret_cast<sockaddr*>(&from), &length);
    if (size < 0) return false;
    datagram->resize(static_cast<size_t>(size));
    *sender = (uint64_t{ntohl(from.sin_addr.s_addr)} << 16) | ntohs(from.sin_port);
    return true;
  }

 private:
  int fd_ = -1;
};

// On this host (ttl=0, no mtu) the sender's datagrams are liblcm's, byte for byte, so lcm-spy,
// lcm-logger and lcm-logplayer read them; each message has the next msg_seqno.
TEST(UdpmSenderTest, OnOneHostTheDatagramsAreLiblcms) {
  const UdpmAddress address = ParseUdpmUrl(testing::FreeMulticastUrl());
  RawMulticastReceiver receiver(address);
  UdpmSender sender(address);
  EXPECT_EQ(sender.max_datagram(), testing::kLcmFragmentPayload + 20);
  const std::vector<uint8_t> small = Payload(1000, 1), large = Payload(200000, 2);
  sender.Send(kChannel, small.data(), small.size());
  sender.Send(kChannel, large.data(), large.size());
  std::vector<std::vector<uint8_t>> expected = LcmDatagrams(kChannel, small, 0);
  for (const auto& datagram : LcmDatagrams(kChannel, large, 1)) expected.push_back(datagram);
  std::vector<uint8_t> datagram;
  uint64_t from = 0;
  for (const auto& want : expected) {
    ASSERT_TRUE(receiver.Next(2000, &datagram, &from));
    EXPECT_EQ(datagram, want);
    EXPECT_EQ(from & 0xFFFF, sender.port());
  }
}

// Across hosts (mtu=1500) no datagram is larger than an Ethernet frame's payload, and a receiver
// that loses 30 % of them gets every message whole by asking for the missing fragments: the
// sender sends them again under the same msg_seqno.
TEST(UdpmSenderTest, SmallDatagramsAndRepairsGetThroughThirtyPercentLoss) {
  UdpmAddress address = ParseUdpmUrl(testing::FreeMulticastUrl());
  address.mtu = 1500;
  RawMulticastReceiver receiver(address);
  UdpmSender sender(address);
  EXPECT_EQ(sender.max_datagram(), 1472u);
  std::vector<std::vector<uint8_t>> sent;
  std::vector<UdpmRepair> asks;
  UdpmLimits limits;
  limits.repair_after_s = 0.01;
  limits.max_repair_asks = 1000;
  UdpmReassembler reassembler(
      limits, [](const std::string& channel) { return channel == kChannel; },
      [&asks](const UdpmRepair& ask) {
        asks.push_back(ask);
        return true;
      });
  std::mt19937_64 loss(42);
  std::vector<std::vector<uint8_t>> received;
  int datagrams = 0, dropped = 0;
  for (uint32_t i = 0; i < 3; ++i) {
    sent.push_back(Payload(300000 + i, 10 + i));
    sender.Send(kChannel, sent.back().data(), sent.back().size());
  }
  std::vector<uint8_t> datagram;
  uint64_t from = 0;
  for (int idle = 0; received.size() < sent.size() && idle < 100;) {
    if (!receiver.Next(5, &datagram, &from)) {
      ++idle;
      reassembler.Expire();
      for (const UdpmRepair& ask : asks) sender.Repair(ask);
      asks.clear();
      continue;
    }
    idle = 0;
    ++datagrams;
    EXPECT_LE(datagram.size(), 1472u);
    if (loss() % 100 < 30) {
      ++dropped;
      continue;
    }
    UdpmMessage message;
    if (reassembler.Add(from, datagram.data(), datagram.size(), &message)) {
      received.emplace_back(message.data.get(), message.data.get() + message.size);
    }
  }
  std::printf("%d datagrams, %d dropped, %lld asks, %lld fragments sent again\n", datagrams,
              dropped, static_cast<long long>(reassembler.counters().repair_asks),
              static_cast<long long>(sender.repaired_fragments()));
  // in any order: one whose fragment 0 was lost completes after it was asked for
  std::sort(received.begin(), received.end());
  std::sort(sent.begin(), sent.end());
  EXPECT_EQ(received, sent);
  EXPECT_EQ(reassembler.counters().repaired, 3);
  EXPECT_GT(sender.repaired_fragments(), 100);
}

}  // namespace
}  // namespace stackgen
