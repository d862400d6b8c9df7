#pragma once

// LCM's UDP multicast transport, received by stackgen itself (design.md, "Trust": no datagram
// can crash a process or grow its memory past a bound, whatever the LCM library does).
//
// Why not liblcm's receiver: liblcm 1.3.1 reassembles a fragmented message before any check of
// ours can run, and tests a fragment's end as `fragment_offset + frag_size > data_size` in 32
// bits: an offset of 0xFFFFFF00 wraps the sum and memcpy writes about 4 GB past a heap buffer
// (two datagrams kill any process subscribed to the channel, bus key or not; lcm-proj/lcm pull
// request 628 is still open, no packaged LCM has the fix). It also reads a fragment's channel
// with an unbounded strlen and counts a repeated fragment twice, so that a message completes
// with bytes that never arrived. Patching liblcm would mean building LCM from a pinned source in
// every checkout; the receiving half of one transport is smaller, and here every field is
// checked before it is used and memory has a bound. Sending stays with liblcm (it only handles
// our own bytes), so the bytes on the group are LCM's and lcm-spy, lcm-logger and lcm-logplayer
// keep working.
//
// The wire format (lcm-proj/lcm, lcm/udpm_util.h and lcm_udpm.c), integers big-endian:
//   a short message, one datagram:
//     "LC02" | msg_seqno u32 | channel, NUL-terminated | message bytes
//   one fragment of a message too large for one datagram:
//     "LC03" | msg_seqno u32 | msg_size u32 | fragment_offset u32 | fragment_no u16 |
//     fragments_in_msg u16 | channel, NUL-terminated (fragment 0 only) |
//     message bytes [fragment_offset, fragment_offset + n)
//
// What is taken; everything else is dropped and counted, never trusted:
// - a channel of 1..63 bytes (LCM_MAX_CHANNEL_NAME_LENGTH) ended by a NUL inside the datagram;
//   only channels subscribed to are kept (before anything is allocated for a message);
// - the fragments of one message come from one sender (address and port), as liblcm sends them,
//   and a sender has one message in reassembly at a time: a fragment of another message
//   (msg_seqno, msg_size or fragment count) ends the one before, as in liblcm;
// - a message starts with its fragment 0, at offset 0 (a fragment of a message whose fragment 0
//   was not heard is dropped, as in liblcm); its size is 1..max_message_bytes, its fragment
//   count 1..65535; each fragment holds at least one byte, lies inside the message (64-bit
//   arithmetic), comes once and overlaps no other; the message is complete when all its
//   fragments have come and cover it exactly;
// - memory: a message in reassembly holds the fragments heard, nothing for what it only claims;
//   the messages in reassembly hold at most max_partial_bytes together, counted with their
//   bookkeeping (a record per message, one per fragment), and number at most max_partials (the
//   one heard from least recently gives way); a message that could not fit whole is never
//   begun; one that hears no fragment for partial_timeout_s is given up, its memory freed;
//   complete messages waiting to be handled hold at most max_queued_bytes, and each channel at
//   most its queue capacity (a message beyond either is dropped, as liblcm drops one beyond a
//   subscription's queue).

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

namespace stackgen {

/// The group, port and receive buffer of a udpm:// URL.
struct UdpmAddress {
  /// The IPv4 multicast group, host byte order.
  uint32_t group = 0;
  uint16_t port = 7667;
  /// recv_buf_size=N: the kernel receive buffer to ask for (bytes; 0: the system's default).
  int recv_buf_size = 0;
};

/// Parses "udpm://GROUP[:PORT][?key=value&...]". Throws std::runtime_error naming the URL when
/// it is not a udpm:// URL of an IPv4 multicast group, or its port or recv_buf_size is bad.
UdpmAddress ParseUdpmUrl(const std::string& url);

/// What receiving may hold in memory (see the file comment).
struct UdpmLimits {
  /// The largest message taken (bytes, its bus-key trailer included). Default 256 MiB + 64.
  size_t max_message_bytes = (size_t{256} << 20) + 64;
  /// What the messages in reassembly may hold together (bytes heard and bookkeeping). Default
  /// 64 MiB; a message that would hold more whole is not received.
  size_t max_partial_bytes = size_t{64} << 20;
  /// Messages in reassembly at once, of different senders. Default 64.
  int max_partials = 64;
  /// A message in reassembly that hears no fragment for this long is given up (seconds; liblcm
  /// sends a message's fragments back to back). Default 2.
  double partial_timeout_s = 2;
  /// Complete messages waiting to be handled, all channels together (bytes). Default 1 GiB.
  size_t max_queued_bytes = size_t{1} << 30;
};

/// What receiving did with the datagrams it read, since it started.
struct UdpmCounters {
  /// Datagrams read off the socket.
  int64_t datagrams = 0;
  /// Complete messages of subscribed channels handed on (queued).
  int64_t messages = 0;
  /// Datagrams dropped as not LCM, or not consistent with their message (a bad magic, channel,
  /// size, offset, count or a repeated or overlapping fragment). The message they belong to is
  /// dropped with them.
  int64_t malformed = 0;
  /// Messages in reassembly given up: another message of their sender began, or memory for
  /// reassembly ran out (max_partial_bytes, max_partials) and they were the least recent.
  int64_t abandoned = 0;
  /// Complete messages refused by the admit check (the bus key), not queued.
  int64_t refused = 0;
  /// Complete messages dropped because their channel's queue or max_queued_bytes was full.
  int64_t queue_full = 0;
};

/// "received D datagrams: M malformed, A messages given up incomplete, Q dropped for a full
/// queue": how the programs' summary lines say it.
std::string ReceiveSummary(const UdpmCounters& counters);

/// One message off the wire: its channel and bytes.
struct UdpmMessage {
  std::string channel;
  std::unique_ptr<uint8_t[]> data;
  size_t size = 0;
};

/// Turns datagrams into messages (see the file comment): the checks and bounds, without a
/// socket or a thread, so that tests hand it any bytes. Not thread-safe.
class UdpmReassembler {
 public:
  /// `wanted` says whether a channel is subscribed to (called before anything is allocated).
  UdpmReassembler(const UdpmLimits& limits, std::function<bool(const std::string&)> wanted);
  ~UdpmReassembler();
  UdpmReassembler(const UdpmReassembler&) = delete;
  UdpmReassembler& operator=(const UdpmReassembler&) = delete;

  /// Takes one datagram from `sender` (its address and port, as one number) at `now_s` (seconds
  /// on a steady clock; without it, now), giving up messages timed out first. Returns true and
  /// fills `*message` when the datagram completes a message of a wanted channel.
  bool Add(uint64_t sender, const uint8_t* data, size_t size, UdpmMessage* message);
  bool Add(uint64_t sender, const uint8_t* data, size_t size, double now_s, UdpmMessage* message);
  /// Gives up the messages that heard no fragment for partial_timeout_s (at `now_s`, or now).
  void Expire();
  void Expire(double now_s);

  /// The bytes the messages in reassembly hold now (bookkeeping included), and how many they are.
  size_t partial_bytes() const;
  int partials() const;
  /// Counted so far (datagrams, messages, malformed, abandoned; the rest stay 0 here).
  const UdpmCounters& counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// A socket joined to a udpm:// group and a thread of its own that reads it, reassembles
/// messages (UdpmReassembler) and queues those of subscribed channels until Take. The thread
/// blocks every signal, so SIGINT and SIGTERM reach the program's other threads.
class UdpmReceiver {
 public:
  /// Called on the receiving thread for each complete message before it is queued; false drops
  /// it (counted as refused). May keep nothing of the message beyond the call.
  using Admit = std::function<bool(const UdpmMessage&)>;
  /// What Take did.
  enum class Taken { kMessage, kTimeout, kInterrupted };

  /// Binds the port of `address` (shared with other processes: SO_REUSEADDR), joins the group,
  /// sets the receive buffer and starts the thread. `program` names the process in the one
  /// warning it may print (a receive buffer smaller than asked for). Throws std::runtime_error
  /// naming the group and the call that failed.
  UdpmReceiver(const UdpmAddress& address, const UdpmLimits& limits, Admit admit,
               const std::string& program);
  /// Stops and joins the thread.
  ~UdpmReceiver();
  UdpmReceiver(const UdpmReceiver&) = delete;
  UdpmReceiver& operator=(const UdpmReceiver&) = delete;

  /// Keeps messages of `channel` (an exact name), at most `queue_capacity` of them waiting;
  /// subscribing again raises the capacity to the larger one. Thread-safe.
  void Subscribe(const std::string& channel, int queue_capacity);
  /// Also keeps messages of every channel `matches` says yes to (a recorder's pattern), each
  /// channel at most `queue_capacity` waiting, kMaxMatchedChannels channels at most (a
  /// stranger's channel names cannot grow the table without bound). Thread-safe.
  void SubscribeMatching(std::function<bool(const std::string&)> matches, int queue_capacity);
  static constexpr size_t kMaxMatchedChannels = 256;

  /// The oldest queued message, waiting up to `timeout_ms` for one (0: only one already
  /// queued). kInterrupted when a signal interrupted the wait.
  Taken Take(int timeout_ms, UdpmMessage* message);

  /// Counted so far. Thread-safe.
  UdpmCounters counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen
