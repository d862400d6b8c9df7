#pragma once

// Authenticated messages (design.md, "Trust"): with a bus key shared by the processes of one
// deployment, every message a Bus publishes carries a trailer after its LCM bytes:
//
//   sender (8 bytes) | counter (8) | utime (8) | MAC (32) | magic "SGAUTH01" (8)
//
// all integers big-endian. `sender` is a random id drawn once per Bus (OpenSSL's RAND_bytes),
// `counter` counts that Bus's messages from 1, `utime` is the sending time in microseconds since
// the Unix epoch, and MAC is HMAC-SHA256 (OpenSSL) keyed with the bus key over the channel
// name, the LCM bytes and the three fields before it. A receiver with the key refuses a message
// without a trailer (unsigned), one whose MAC does not match (forged, altered, or signed with
// another key) and one it has seen before (its sender's counter seen already, or too old: the
// newest 1024 counters of each sender are remembered; on a live bus a message stamped more than
// kMaxMessageAgeS away from the receiver's clock is refused too, which stops a message recorded
// earlier from being replayed to a process that never saw its sender). Stock LCM tools
// (lcm-spy, lcm-logger, lcm-logplayer, lcm-gen's Python types) decode a message and ignore the
// bytes after it, so they keep working; a log keeps the trailers and replays on a file:// bus
// with the key it was recorded under.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace stackgen {

/// Bytes the trailer adds to every message published with a key.
inline constexpr size_t kAuthTrailerBytes = 64;
/// A message stamped further than this from the receiver's clock is refused on a live bus
/// (seconds): a replay of something recorded earlier. Hosts of one LAN need clocks within it.
inline constexpr double kMaxMessageAgeS = 60;
/// The fewest bytes a bus key file must hold (after trailing white space is dropped).
inline constexpr size_t kMinBusKeyBytes = 32;

/// The key file to use: `flag_value` when not empty, else $STACKGEN_BUS_KEY_FILE when set, else
/// "" (no key).
std::string ResolveBusKeyFile(const std::string& flag_value);

/// Messages refused by a MessageAuth, by reason.
struct AuthCounters {
  /// Messages without a trailer (sent by a process with no key).
  int64_t unsigned_messages = 0;
  /// Messages whose MAC does not match: forged, altered on the way, or signed with another key.
  int64_t forged = 0;
  /// Messages seen before (a counter of their sender seen already or too old), or stamped too
  /// far from now on a live bus.
  int64_t replayed = 0;
  int64_t total() const { return unsigned_messages + forged + replayed; }
};

/// Seals outgoing and checks incoming messages of one Bus. Without a key it seals nothing and
/// passes every message on (a trailer, if any, is cut off unchecked). Not thread-safe, except
/// Verify and the counters, which may run beside the other calls.
class MessageAuth {
 public:
  /// Reads the key from `key_file` ("" for none). The file must be a regular file of at least
  /// kMinBusKeyBytes bytes (64 KiB at most) that other users cannot read or write; its bytes,
  /// without trailing white space, are the key. `live`: the bus is live (udpm://, memq://), so
  /// messages stamped too far from now are refused; false for a file:// log. Throws
  /// std::runtime_error naming the file and what is wrong with it.
  MessageAuth(const std::string& key_file, bool live);
  ~MessageAuth();
  MessageAuth(const MessageAuth&) = delete;
  MessageAuth& operator=(const MessageAuth&) = delete;

  /// True when a key was given.
  bool keyed() const;
  /// The key file given ("" for none).
  const std::string& key_file() const;

  /// `data` followed by its trailer for `channel` (with a key), or `data` alone (without).
  void Seal(const std::string& channel, const uint8_t* data, size_t size,
            std::vector<uint8_t>* sealed);

  /// Checks a message received on `channel` at `now_us` (microseconds since the Unix epoch):
  /// Verify, then Admit. Returns the size of its LCM bytes (the trailer cut off), or -1 when it
  /// is refused: then it is counted and `*why` (when not null) says why in one line naming the
  /// channel.
  int64_t Open(const std::string& channel, const uint8_t* data, size_t size, int64_t now_us,
               std::string* why);

  /// The first half of Open, safe to call from any thread (a receiving thread checks messages
  /// before it queues them): refuses a message that is not signed or whose MAC does not match.
  /// Returns the size of its LCM bytes, or -1 (counted, with `*why`).
  int64_t Verify(const std::string& channel, const uint8_t* data, size_t size, std::string* why);

  /// The second half of Open, for a message Verify passed, on one thread only: refuses one seen
  /// before, or stamped too far from `now_us` on a live bus. Returns the size of its LCM bytes,
  /// or -1 (counted, with `*why`).
  int64_t Admit(const std::string& channel, const uint8_t* data, size_t size, int64_t now_us,
                std::string* why);

  /// What was refused so far.
  AuthCounters counters() const;
  /// Messages sealed and opened with the key so far, and the seconds that took (what the key
  /// costs; 0 without one).
  int64_t messages() const;
  double seconds() const;

 private:
  struct Impl;
  class Timed;
  std::unique_ptr<Impl> impl_;
};

/// Microseconds since the Unix epoch, now (the clock of every header.utime and of the trailer).
int64_t UnixMicros();

/// "refused U unsigned, F forged or altered, R replayed": how the programs' summary lines say it.
std::string RefusedSummary(const AuthCounters& counters);

}  // namespace stackgen
