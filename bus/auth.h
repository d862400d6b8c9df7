#pragma once

// Authenticated messages (docs/design.md, "Trust"). Every process of a deployment shares a bus key,
// on by default: a key file given by --bus-key-file or $STACKGEN_BUS_KEY_FILE, else this user's
// key at $XDG_CONFIG_HOME/stackgen/bus.key (~/.config/stackgen/bus.key), made with mode 600 on
// first use. Running without one (an open bus, every sender trusted) takes an explicit choice:
// --open-bus, or open_bus=True in Python.
//
// With the key, every message a Bus publishes carries a trailer after its LCM bytes:
//
//   sender (8 bytes) | counter (8) | key id (8) | bus (8) | MAC (32) | magic "SGAUTH03" (8)
//
// all integers big-endian. `sender` is a random id drawn once per Bus (OpenSSL's RAND_bytes),
// `counter` counts that Bus's messages from 1, `key id` is the first 8 bytes of
// HMAC-SHA256(key, "stackgen bus key id"), the same for every holder of the key and telling
// nothing else about it (a process that hears another key's id can say so), `bus` is the bus it
// was published on (BusTag: a udpm:// group and port; 0 for a log written by a LogAppender),
// and MAC is HMAC-SHA256 keyed with the bus key over the channel name, the LCM bytes and the
// four fields before it. A receiver with the key refuses a message without a trailer (unsigned),
// one of another key id or whose MAC does not match (forged, altered, or signed with another
// key), on a live bus one signed for another bus (relayed from another group or port), and one
// it has seen before (its sender's counter seen already, or too old: the newest 1024 counters
// of each sender are remembered).
//
// Replays are bound to the run, not to a time window: on a live bus a receiver takes a sender's
// messages only once that sender has answered a liveness challenge (bus/liveness.h: a random
// nonce on STACKGEN_LIVENESS, answered in a signed message), and only the messages the sender
// signed after that answer. A recording played back onto the bus cannot answer (its sender is
// gone, or, if it still runs, everything recorded is older than its answer), so it is refused
// whatever its age; a consumer told that it reads a replay (--replay) skips the challenge, and a
// file:// log is always read as one. Stock LCM tools (lcm-spy, lcm-logger, lcm-logplayer,
// lcm-gen's Python types) decode a message and ignore the bytes after it, so they keep working;
// a log keeps the trailers and replays with the key it was recorded under.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace stackgen {

/// Bytes the trailer adds to every message published with a key.
inline constexpr size_t kAuthTrailerBytes = 72;
/// The fewest bytes a bus key file must hold (after trailing white space is dropped).
inline constexpr size_t kMinBusKeyBytes = 32;

/// This user's bus key file: $XDG_CONFIG_HOME/stackgen/bus.key, else $HOME/.config/stackgen/
/// bus.key. Throws std::runtime_error when neither variable is set.
std::string DefaultBusKeyFile();

/// Makes a bus key at `path` unless a file is there: 32 random bytes (OpenSSL), base64, mode
/// 600, its folder made (mode 700) when missing; written under a temporary name and linked into
/// place, so processes starting at once share one key. Returns true when it made it. Throws
/// std::runtime_error naming the path when it cannot.
bool MakeBusKeyFile(const std::string& path);

/// The key file to use: `flag_value` when not empty, else $STACKGEN_BUS_KEY_FILE when set, else
/// DefaultBusKeyFile(), made when missing (with one line on stderr saying where).
std::string ResolveBusKeyFile(const std::string& flag_value);

/// A key id as 16 hex digits.
std::string KeyIdText(uint64_t key_id);

/// Messages refused by a MessageAuth, by reason.
struct AuthCounters {
  /// Messages without a trailer (sent by a process with no key).
  int64_t unsigned_messages = 0;
  /// Messages of another key id, or whose MAC does not match: forged, altered on the way.
  int64_t forged = 0;
  /// Messages seen before (a counter of their sender seen already or too old), sent before
  /// their sender answered this process's liveness challenge, or of a sender that never
  /// answered (a recording played back onto the bus).
  int64_t replayed = 0;
  /// Messages signed for another bus (a relay from another group or port), on a live bus.
  int64_t relayed = 0;
  int64_t total() const { return unsigned_messages + forged + replayed + relayed; }
};

/// The fields of a message's trailer.
struct Trailer {
  uint64_t sender = 0;
  uint64_t counter = 0;
  uint64_t key_id = 0;
  uint64_t bus = 0;
};

/// The bus a udpm:// URL names, as a trailer carries it: its IPv4 group and port
/// ((group << 16) | port); 0 for any other URL.
uint64_t BusTag(const std::string& url);
/// "239.255.76.67:7667" for a tag, "no bus (a log)" for 0.
std::string BusTagText(uint64_t bus);

/// Reads the trailer of a message; false when it has none (unsigned). Checks nothing else.
bool ReadTrailer(const uint8_t* data, size_t size, Trailer* trailer);

/// Seals outgoing and checks incoming messages of one Bus. Without a key it seals nothing and
/// passes every message on (a trailer, if any, is cut off unchecked). Thread-safe: a receiving
/// thread verifies while the program seals and admits.
class MessageAuth {
 public:
  /// Reads the key from `key_file` ("" for none: an open bus). The file must be a regular file of
  /// at least kMinBusKeyBytes bytes (64 KiB at most) that other users cannot read or write; its
  /// bytes, without trailing white space, are the key. `liveness`: a sender's messages are taken
  /// only once it has answered a liveness challenge (Proven), as on a live bus; false for a log
  /// and for a consumer told that it reads a replay. `bus` (BusTag) goes into what it seals,
  /// and with `liveness` a message signed for another bus is refused (relayed); 0: none (a log).
  /// Throws std::runtime_error naming the file and what is wrong with it.
  MessageAuth(const std::string& key_file, bool liveness, uint64_t bus = 0);
  ~MessageAuth();
  MessageAuth(const MessageAuth&) = delete;
  MessageAuth& operator=(const MessageAuth&) = delete;

  /// True when a key was given.
  bool keyed() const;
  /// The key file given ("" for none), its key id (0 without one), and this Bus's sender id.
  const std::string& key_file() const;
  uint64_t key_id() const;
  uint64_t sender() const;
  /// Whether senders must answer a liveness challenge before their messages are taken.
  bool liveness() const;
  /// The bus its messages are sealed for (BusTag; 0: none).
  uint64_t bus() const;

  /// `data` followed by its trailer for `channel` (with a key), or `data` alone (without).
  /// Returns the counter the trailer carries (0 without a key).
  uint64_t Seal(const std::string& channel, const uint8_t* data, size_t size,
                std::vector<uint8_t>* sealed);

  /// Checks a message received on `channel`: Verify, then Admit. Returns the size of its LCM
  /// bytes (the trailer cut off), or -1 when it is refused: then it is counted and `*why` (when
  /// not null) says why in one line naming the channel.
  int64_t Open(const std::string& channel, const uint8_t* data, size_t size, std::string* why);

  /// The first half of Open: refuses a message that is not signed, signed with another key,
  /// whose MAC does not match, or (with liveness and a bus) signed for another bus. Returns the size of its LCM bytes, or -1 (counted, with `*why`).
  int64_t Verify(const std::string& channel, const uint8_t* data, size_t size, std::string* why);

  /// The second half, for a message Verify passed: refuses one of a sender that has not
  /// answered a liveness challenge (when liveness() holds), one its sender signed before it
  /// answered, and one seen before. Returns the size of its LCM bytes, or -1 (counted, with
  /// `*why`).
  int64_t Admit(const std::string& channel, const uint8_t* data, size_t size, std::string* why);

  /// Whether messages of `sender` are taken now: liveness() does not hold, `sender` is this Bus,
  /// or it has answered.
  bool Live(uint64_t sender) const;
  /// `sender` answered a liveness challenge in its message `counter`: its messages signed after
  /// that one are taken from now on.
  void Proven(uint64_t sender, uint64_t counter);
  /// Counts one message refused because its sender does not answer (as replayed).
  void CountUnanswered();
  /// Senders that have answered so far.
  int64_t answered() const;

  /// What was refused so far.
  AuthCounters counters() const;
  /// Messages sealed and verified with the key so far, and the seconds signing and checking
  /// took (what the key costs; 0 without one).
  int64_t messages() const;
  double seconds() const;

 private:
  struct Impl;
  class Timed;
  std::unique_ptr<Impl> impl_;
};

/// What the messages a process heard showed of their senders' keys: a process whose peers all
/// use another key (or none, or which has none while they sign) can say so in one line instead
/// of waiting for ever.
struct KeyEvidence {
  /// Messages signed with this process's key (keyed), or unsigned (open).
  int64_t taken = 0;
  /// Messages of another key or unsigned (keyed), or signed (open).
  int64_t mismatched = 0;
  int64_t unsigned_messages = 0;
  /// Keyed: messages that carry this process's key id but fail its check (forged or altered),
  /// and of those, the ones signed for another bus (relayed).
  int64_t forged = 0;
  int64_t relayed = 0;
  /// The key id of the last message of another key (0: none heard).
  uint64_t other_key_id = 0;

  /// Notes one message: `verified` is what MessageAuth::Verify said of it.
  void Note(const MessageAuth& auth, const uint8_t* data, size_t size, bool verified);
  /// Adds another's counts.
  void Add(const KeyEvidence& other);
  /// One line saying that `what` (e.g. "the messages on STACKGEN_SCENE of URL") came from
  /// processes with another key than `auth`'s, with none, or (auth open) with one, and what to
  /// do, or (keyed, no other key id heard) that they carry this key's id but fail its check;
  /// "" when nothing shows it (one message this process could take is enough). Nothing heard
  /// here is verified: a stranger can send any of it, so programs say the line and go on
  /// waiting (a live bus), or give it as the reason when they end for a reason of their own.
  std::string Mismatch(const MessageAuth& auth, const std::string& what) const;
};

/// Microseconds since the Unix epoch, now (the clock of every header.utime).
int64_t UnixMicros();

/// "refused U unsigned, F forged or altered, R replayed": how the programs' summary lines say it.
std::string RefusedSummary(const AuthCounters& counters);

}  // namespace stackgen
