#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "bus/auth.h"
#include "bus/clock.h"
#include "bus/udpm.h"
#include "contract/bounded_decode.h"

namespace stackgen {

/// The default bus URL: UDP multicast on this host only, with a 4 MiB receive buffer.
inline constexpr const char* kDefaultLcmUrl =
    "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304";

/// The URL to use: `flag_value` when not empty, else $STACKGEN_LCM_URL when set, else
/// kDefaultLcmUrl.
std::string ResolveLcmUrl(const std::string& flag_value);

/// Thrown when a message on a channel cannot be decoded; the text names the channel.
class DecodeError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Fault injection, for tests and demos: the bus drops a fraction of the messages it receives
/// (before any handler sees them) and of those it publishes, drawn per channel from an engine
/// seeded with (`fault_seed`, channel), so a run is repeatable and the drops on one channel do
/// not depend on how many messages the others carried.
struct BusOptions {
  /// Fraction of received messages dropped, 0..1 (default 0: none).
  double drop_receive_fraction = 0;
  /// Fraction of published messages not sent, 0..1 (default 0: none).
  double drop_publish_fraction = 0;
  /// Seed of the drop engine.
  uint64_t fault_seed = 1;
  /// What decoding one received message may allocate (see DecodeBounded).
  DecodeLimits decode_limits;
  /// The bus key file (see auth.h): "" (the default) means ResolveBusKeyFile's choice:
  /// $STACKGEN_BUS_KEY_FILE when set, else this user's key (made on first use). Every message
  /// published is signed and every message received must be signed with it (others are refused
  /// and counted: auth_counters).
  std::string key_file;
  /// No key at all: every sender is trusted (--open-bus). A udpm:// bus warns once per process
  /// on stderr that it is open.
  bool open_bus = false;
  /// The consumer reads a recording played back onto a live bus (--replay): messages are taken
  /// without their sender answering the liveness check (auth.h), whatever their age. A file://
  /// log is always read so.
  bool replay = false;
  /// The clock KeyMismatch's `seconds` are measured on; null: SteadyClock(). Must outlive the
  /// bus, and be safe to read from the thread that receives (SteadyClock is).
  Clock* clock = nullptr;
};

/// The LCM encoding of `message`. Throws std::runtime_error if it cannot be encoded.
template <typename Message>
std::vector<uint8_t> EncodeMessage(const Message& message) {
  std::vector<uint8_t> bytes(static_cast<size_t>(message.getEncodedSize()));
  if (message.encode(bytes.data(), 0, static_cast<int>(bytes.size())) < 0) {
    throw std::runtime_error(std::string("cannot encode a ") + Message::getTypeName());
  }
  return bytes;
}

/// What Bus::Subscribe returns: its handler's registration. By default dropping it changes
/// nothing (the handler stays for the bus's life, as most programs want); after
/// EndWhenDropped() the handler is removed when the Subscription is destroyed or Reset, so an
/// object that subscribes with its own `this` (SceneServer, SceneClient, the generator node, a
/// writer session) can be destroyed before its bus (after which the bus may go on handling
/// messages). A Subscription may outlive its bus. Move-only; not thread-safe, like the bus.
class Subscription {
 public:
  Subscription() = default;
  ~Subscription() { Reset(); }
  Subscription(Subscription&& other) noexcept { *this = std::move(other); }
  Subscription& operator=(Subscription&& other) noexcept {
    if (this != &other) {
      Reset();
      slot_ = std::move(other.slot_);
      end_when_dropped_ = other.end_when_dropped_;
      other.end_when_dropped_ = false;
    }
    return *this;
  }
  Subscription(const Subscription&) = delete;
  Subscription& operator=(const Subscription&) = delete;

  /// The handler ends with this object (returns it, so `sub_ = bus.Subscribe(...).EndWhenDropped()`
  /// reads as it works).
  Subscription&& EndWhenDropped() && {
    end_when_dropped_ = true;
    return std::move(*this);
  }
  /// Removes the handler now when it ends with this object; keeps it otherwise.
  void Reset();
  /// Whether the handler is still called (false once removed, or when the bus is gone).
  bool active() const;

 private:
  friend class Bus;
  struct Slot;
  explicit Subscription(std::weak_ptr<Slot> slot) : slot_(std::move(slot)) {}
  std::weak_ptr<Slot> slot_;
  bool end_when_dropped_ = false;
};

class Bus;

/// What a bus knows beyond publishing and handling, apart from Bus's narrow face: its key, what
/// it heard of other processes' keys, and its counters. Each Bus has one (Bus::state()), which
/// lives as long as the bus. Not thread-safe, like the bus.
class BusState {
 public:
  BusState(const BusState&) = delete;
  BusState& operator=(const BusState&) = delete;

  /// Messages dropped on purpose so far (BusOptions), received and published.
  int64_t fault_dropped() const;

  /// True once a file:// bus has handed out the last event of its log.
  bool log_ended() const;

  /// True when the bus signs and checks messages with a key; the key file and its id (auth.h).
  bool keyed() const;
  const std::string& key_file() const;
  uint64_t key_id() const;
  /// One line when what was heard on `channels` shows that the processes sending there use
  /// another bus key than this one (or none, or this bus is open and they sign): messages of
  /// another key (or unsigned, or signed) for at least `seconds` since the first of them, and
  /// not one this bus could take; "" otherwise. None of it is verified: a keyed program says
  /// the line and goes on, or gives it as the reason when it ends for its own (a timeout, a log
  /// that ended); an open one, which verifies nothing, stops with it.
  std::string KeyMismatch(const std::vector<std::string>& channels, double seconds) const;
  /// Hears `channels` for KeyMismatch: each one not subscribed to yet is subscribed with a queue
  /// of one whose messages are dropped unread. KeyMismatch judges only what was heard, so a
  /// consumer that reads scenes but not configs watches both: a generator announces its config
  /// before its first scene (which may take seconds), and a stranger's unsigned scenes heard
  /// meanwhile are not all the evidence.
  void WatchKeys(const std::vector<std::string>& channels);
  /// The handlers subscribed to `channel` now (those whose Subscription ended not counted).
  int handlers(const std::string& channel) const;
  /// What receiving a udpm:// bus did with the datagrams it read (udpm.h; all zero on memq://
  /// and file://): malformed ones dropped, messages given up or dropped for a full queue.
  UdpmCounters receive_counters() const;
  /// Messages received and refused by the key check (all zero without a key).
  AuthCounters auth_counters() const;
  /// Other processes that have answered this bus's liveness check so far (auth.h): each has
  /// been challenged back by then, and takes this bus's messages from its answer on.
  int64_t live_peers() const;
  /// Seconds spent signing and checking messages with the key so far (0 without one).
  double auth_seconds() const;

 private:
  friend class Bus;
  explicit BusState(Bus& bus) : bus_(bus) {}
  Bus& bus_;
};

/// Typed publish/subscribe over LCM. Message types are lcm-gen C++ classes from types/.
/// LCM itself is hidden in bus.cc. Not thread-safe: publish and handle from one thread.
class Bus {
 public:
  /// Opens the bus at `url` (udpm://, memq://, file://). For udpm:// it first checks that
  /// multicast can be sent and throws a one-line error saying how to enable it if not.
  /// `options` sets fault injection (none by default) and the bus key; a key file that cannot be
  /// used throws a one-line error naming it. A keyed bus on udpm:// or memq:// takes a sender's
  /// messages only once it has answered the liveness check (auth.h, liveness.h), unless
  /// options.replay; it answers the checks of other processes itself, on its receiving thread.
  explicit Bus(const std::string& url, const BusOptions& options = {});
  ~Bus();
  Bus(const Bus&) = delete;
  Bus& operator=(const Bus&) = delete;

  /// The URL this bus was opened with.
  const std::string& url() const;

  /// Encodes `message` and publishes it on `channel`. Throws std::runtime_error on failure.
  template <typename Message>
  void Publish(const std::string& channel, const Message& message) {
    const std::vector<uint8_t> bytes = EncodeMessage(message);
    PublishBytes(channel, bytes.data(), bytes.size());
  }

  /// Publishes bytes already encoded (e.g. a scene kept for resending) on `channel`.
  void PublishEncoded(const std::string& channel, const std::vector<uint8_t>& bytes) {
    PublishBytes(channel, bytes.data(), bytes.size());
  }

  /// Calls `handler` for every message on `channel` (an exact name, not a regex), decoded as
  /// `Message` within the bus's DecodeLimits (DecodeBounded: a message of another type, a
  /// corrupt one or one too large is refused before anything large is allocated). A message
  /// that does not decode is not passed on: HandleFor throws a DecodeError naming the channel
  /// and the reason, unless `on_decode_error` is given, which then receives the text.
  /// `queue_capacity` is how many received messages LCM keeps waiting for HandleFor. Handlers
  /// of one channel share one LCM subscription (so each message is checked against the bus key
  /// once) and its queue, of the largest capacity asked for. Returns the handler's
  /// Subscription: kept for the bus's life unless made to EndWhenDropped().
  template <typename Message>
  Subscription Subscribe(const std::string& channel, std::function<void(const Message&)> handler,
                         int queue_capacity = 256,
                         std::function<void(const std::string&)> on_decode_error = nullptr) {
    return SubscribeBytes(
        channel,
        [channel, handler, on_decode_error, limits = decode_limits()](const uint8_t* data,
                                                                      size_t size) {
          Message message;
          std::string why;
          if (!DecodeBounded(data, size, limits, &message, &why)) {
            const std::string text = "cannot decode a " + std::string(Message::getTypeName()) +
                                     " on channel " + channel + " (" + std::to_string(size) +
                                     " bytes): " + why;
            if (on_decode_error) {
              on_decode_error(text);
              return;
            }
            throw DecodeError(text);
          }
          handler(message);
        },
        queue_capacity);
  }

  /// Handles messages that arrive within `timeout_ms` (0: only those already waiting, no wait).
  /// Returns the number of messages handled. An exception thrown by a handler is kept away from
  /// LCM's C code and rethrown here.
  int HandleFor(int timeout_ms);

  /// The bus's key and what it heard of other keys, its counters (BusState).
  BusState& state() { return state_; }
  const BusState& state() const { return state_; }

 private:
  using BytesHandler = std::function<void(const uint8_t* data, size_t size)>;
  const DecodeLimits& decode_limits() const;
  void PublishBytes(const std::string& channel, const uint8_t* data, size_t size);
  Subscription SubscribeBytes(const std::string& channel, BytesHandler handler, int queue_capacity);

  friend class BusState;
  struct Impl;
  std::unique_ptr<Impl> impl_;
  BusState state_{*this};
};

}  // namespace stackgen
