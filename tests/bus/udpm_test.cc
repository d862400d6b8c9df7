#include "bus/udpm.h"

#include <cstdint>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/lcm_wire.h"

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
      {"fragment 0 twice", {good[0], good[0]}},
      {"a fragment twice", {good[0], good[1], good[1]}},
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
  EXPECT_GT(counters.malformed, 5000);
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

// URLs: the group, port and receive buffer are read; what is not a multicast URL is one line.
TEST(UdpmUrlTest, ParsesGroupPortAndBuffer) {
  const UdpmAddress address = ParseUdpmUrl("udpm://239.255.76.67:7811?ttl=0&recv_buf_size=4096");
  EXPECT_EQ(address.group, 0xEFFF4C43u);
  EXPECT_EQ(address.port, 7811);
  EXPECT_EQ(address.recv_buf_size, 4096);
  EXPECT_EQ(ParseUdpmUrl("udpm://239.255.76.67").port, 7667);
  for (const std::string bad :
       {"udpm://10.0.0.1:7667", "udpm://239.255.76.67:0", "udpm://239.255.76.67:x",
        "udpm://239.255.76.67:1?recv_buf_size=-1", "memq://"}) {
    EXPECT_THROW(ParseUdpmUrl(bad), std::runtime_error) << bad;
  }
}

}  // namespace
}  // namespace stackgen
