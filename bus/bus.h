#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

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

/// Typed publish/subscribe over LCM. Message types are lcm-gen C++ classes from types/.
/// LCM itself is hidden in bus.cc. Not thread-safe: publish and handle from one thread.
class Bus {
 public:
  /// Opens the bus at `url` (udpm://, memq://, file://). For udpm:// it first checks that
  /// multicast can be sent and throws a one-line error saying how to enable it if not.
  explicit Bus(const std::string& url);
  ~Bus();
  Bus(const Bus&) = delete;
  Bus& operator=(const Bus&) = delete;

  /// The URL this bus was opened with.
  const std::string& url() const;

  /// Encodes `message` and publishes it on `channel`. Throws std::runtime_error on failure.
  template <typename Message>
  void Publish(const std::string& channel, const Message& message) {
    std::vector<uint8_t> bytes(static_cast<size_t>(message.getEncodedSize()));
    if (message.encode(bytes.data(), 0, static_cast<int>(bytes.size())) < 0) {
      throw std::runtime_error("cannot encode message for channel " + channel);
    }
    PublishBytes(channel, bytes.data(), bytes.size());
  }

  /// Calls `handler` for every message on `channel` (an exact name, not a regex), decoded as
  /// `Message`. A message that does not decode is not passed on: HandleFor throws a DecodeError
  /// naming the channel, unless `on_decode_error` is given, which then receives the text.
  /// `queue_capacity` is how many received messages LCM keeps waiting for HandleFor.
  template <typename Message>
  void Subscribe(const std::string& channel, std::function<void(const Message&)> handler,
                 int queue_capacity = 256,
                 std::function<void(const std::string&)> on_decode_error = nullptr) {
    SubscribeBytes(
        channel,
        [channel, handler, on_decode_error](const uint8_t* data, size_t size) {
          Message message;
          if (message.decode(data, 0, static_cast<int>(size)) < 0) {
            const std::string text = "cannot decode a " + std::string(Message::getTypeName()) +
                                     " on channel " + channel + " (" + std::to_string(size) +
                                     " bytes)";
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

 private:
  using BytesHandler = std::function<void(const uint8_t* data, size_t size)>;
  void PublishBytes(const std::string& channel, const uint8_t* data, size_t size);
  void SubscribeBytes(const std::string& channel, BytesHandler handler, int queue_capacity);

  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen
