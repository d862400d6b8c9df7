#pragma once

// LCM's UDP multicast transport, received by stackgen itself (docs/design.md, "Trust": no datagram
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
// checked before it is used and memory has a bound. Sending is ours too (UdpmSender), for two
// things liblcm cannot do: datagrams no larger than the path's MTU when the bus crosses hosts
// (liblcm sends 64 KB datagrams; one lost frame of the 45 a LAN cuts each into loses it all),
// and sending again the fragments a receiver missed, under the same msg_seqno. The bytes on the
// group stay LCM's, so lcm-spy, lcm-logger and lcm-logplayer keep working.
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
// - the fragments of one message come from one sender (address and port) under one msg_seqno,
//   msg_size and fragment count (a fragment that names another size or count than the message's
//   is malformed); a sender has at most max_partials_per_sender messages in reassembly (its least
//   recent gives way);
// - a message starts with its fragment 0, at offset 0 (a fragment of a message whose fragment 0
//   was not heard is dropped, as in liblcm, and only noted: with repairs, the message asks for
//   its fragment 0 like a missing fragment, max_partials such notes, max_partials_per_sender of
//   one sender); its size is 1..max_message_bytes, its fragment
//   count 1..65535; each fragment holds at least one byte, lies inside the message (64-bit
//   arithmetic) and overlaps no other; a fragment heard again at the same place with the same
//   length is a repeat (a repair can bring one twice) and is dropped (liblcm counted it again);
//   the message is complete when all its fragments have come and cover it exactly; fragments of
//   a message completed lately, or of a channel not wanted (the last 256), are repeats;
// - repair: a message in reassembly that heard nothing for repair_after_s asks its sender for the
//   fragments it lacks (UdpmRepair; the Bus sends it signed on STACKGEN_REPAIR and the sender's
//   UdpmSender sends them again), and again each time repair_after_s passes without one, at most
//   max_repair_asks times in a row without a fragment coming;
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
#include <vector>

namespace stackgen {

/// The group, port and receive buffer of a udpm:// URL.
struct UdpmAddress {
  /// The IPv4 multicast group, host byte order.
  uint32_t group = 0;
  uint16_t port = 7667;
  /// recv_buf_size=N: the kernel receive buffer to ask for (bytes; 0: the system's default).
  int recv_buf_size = 0;
  /// ttl=N: how many links a datagram may cross, 0..255 (0, the default: this host only).
  int ttl = 0;
  /// mtu=N: the largest IP packet sent, 576..65535 bytes; 0 (the default): 65535 with ttl=0
  /// (nothing leaves the host), else the MTU of the interface the route to the group takes.
  int mtu = 0;
};

/// Parses "udpm://GROUP[:PORT][?key=value&...]". Throws std::runtime_error naming the URL when
/// it is not a udpm:// URL of an IPv4 multicast group, its port, recv_buf_size, ttl or mtu is
/// bad, or it has another option.
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
  /// Messages in reassembly from one sender at once. Default 4.
  int max_partials_per_sender = 4;
  /// A message in reassembly that heard no fragment for this long asks for the ones it lacks
  /// (seconds; with no repair callback, never). Default 0.03.
  double repair_after_s = 0.03;
  /// Asks for one message in a row with no fragment coming in between, at most. Default 8.
  int max_repair_asks = 8;
};

/// A message in reassembly asks its sender for the fragments it lacks: bit i of `missing`
/// (least significant bit first in each byte) set says fragment first + i has not come. At most
/// kMaxRepairBits fragments per ask, from the first missing one.
struct UdpmRepair {
  /// The sender's address and port as the receiver saw them (address << 16 | port).
  uint64_t sender = 0;
  uint32_t seqno = 0;
  uint32_t size = 0;
  uint16_t fragments = 0;
  uint32_t first = 0;
  std::vector<uint8_t> missing;
};
inline constexpr uint32_t kMaxRepairBits = 8192;

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
  /// Fragments heard again (a repair that crossed the first copy), dropped.
  int64_t repeats = 0;
  /// Asks for missing fragments sent (UdpmRepair), and messages completed after one.
  int64_t repair_asks = 0;
  int64_t repaired = 0;
};

/// "received D datagrams: M malformed, A messages given up incomplete, Q dropped for a full
/// queue, R completed by asking for K repairs": how the programs' summary lines say it.
std::string ReceiveSummary(const UdpmCounters& counters);

/// One message off the wire: its channel and bytes.
struct UdpmMessage {
  std::string channel;
  std::unique_ptr<uint8_t[]> data;
  size_t size = 0;
  /// Its sender's address and port (address << 16 | port).
  uint64_t sender = 0;
};

/// Turns datagrams into messages (see the file comment): the checks and bounds, without a
/// socket or a thread, so that tests hand it any bytes. Not thread-safe.
class UdpmReassembler {
 public:
  /// Called when a message in reassembly asks for the fragments it lacks; true when the ask was
  /// sent (counted in repair_asks), false when not (the sender is not asked: not a peer).
  using Repair = std::function<bool(const UdpmRepair&)>;
  /// `wanted` says whether a channel is subscribed to (called before anything is allocated).
  /// `repair`, when given, is called for the asks (see the file comment), from Add and Expire.
  UdpmReassembler(const UdpmLimits& limits, std::function<bool(const std::string&)> wanted,
                  Repair repair = nullptr);
  ~UdpmReassembler();
  UdpmReassembler(const UdpmReassembler&) = delete;
  UdpmReassembler& operator=(const UdpmReassembler&) = delete;

  /// Takes one datagram from `sender` (its address and port, as one number) at `now_s` (seconds
  /// on a steady clock; without it, now), giving up messages timed out first. Returns true and
  /// fills `*message` when the datagram completes a message of a wanted channel.
  bool Add(uint64_t sender, const uint8_t* data, size_t size, UdpmMessage* message);
  bool Add(uint64_t sender, const uint8_t* data, size_t size, double now_s, UdpmMessage* message);
  /// Gives up the messages that heard no fragment for partial_timeout_s (at `now_s`, or now), and
  /// asks for the missing fragments of those due (repair_after_s).
  void Expire();
  void Expire(double now_s);
  /// How long until Expire has something to do, at the soonest (seconds; < 0: nothing in
  /// reassembly).
  double NextDue(double now_s) const;

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
  /// `repair`: see UdpmReassembler (called on the receiving thread).
  UdpmReceiver(const UdpmAddress& address, const UdpmLimits& limits, Admit admit,
               const std::string& program, UdpmReassembler::Repair repair = nullptr);
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

/// Sends messages onto a udpm:// group as LCM does (the wire format above), in datagrams of at
/// most the MTU (UdpmAddress::mtu) less the IP and UDP headers, and keeps the fragmented ones it
/// sent lately (max_kept_bytes together) so that it can send a receiver's missing fragments
/// again (Repair). Thread-safe: the program publishes while the receiving thread answers.
class UdpmSender {
 public:
  /// What it keeps for repairs: the fragmented messages sent lately, this many bytes together
  /// (the newest always kept). Default 32 MiB.
  static constexpr size_t kDefaultKeptBytes = size_t{32} << 20;

  /// Opens a socket for `address` (its group, port, ttl and mtu). Throws std::runtime_error
  /// naming the group and the call that failed.
  explicit UdpmSender(const UdpmAddress& address, size_t max_kept_bytes = kDefaultKeptBytes);
  ~UdpmSender();
  UdpmSender(const UdpmSender&) = delete;
  UdpmSender& operator=(const UdpmSender&) = delete;

  /// Sends `data` on `channel`. Throws std::runtime_error when it cannot (a message that needs
  /// more than 65535 fragments at this MTU, a failed send), naming the channel.
  void Send(const std::string& channel, const uint8_t* data, size_t size);

  /// Sends again the fragments `repair` asks for, of a message this sender sent lately (its
  /// port, msg_seqno, size and fragment count match). Each fragment is sent again at most once
  /// in 10 ms (several receivers asking at once cost one). Returns the fragments sent.
  int Repair(const UdpmRepair& repair);

  /// The port the datagrams come from (what receivers see in UdpmRepair::sender's low 16 bits).
  uint16_t port() const;
  /// The largest datagram it sends (UDP payload bytes).
  size_t max_datagram() const;
  /// Fragments sent again for repairs so far.
  int64_t repaired_fragments() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen
