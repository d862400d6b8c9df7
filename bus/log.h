#pragma once

// LCM log files (the event log format of lcm-logger and lcm-logplayer): reading and writing
// typed messages. LCM itself is hidden in log.cc: it writes the logs; reading parses the format
// there, so that a corrupt log is one clear error.

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "bus/auth.h"
#include "bus/bus.h"

namespace stackgen {

/// The first four bytes of every event in an LCM log, big-endian.
inline constexpr uint32_t kLcmLogMagic = 0xEDA1DA01;

/// True when the file at `path` starts with an LCM log event (kLcmLogMagic). False when it
/// cannot be read or starts with anything else.
bool IsLcmLog(const std::string& path);

/// One event of a log: valid only during the call that receives it.
struct LogEvent {
  /// Event number, as written by the logger (0, 1, ...; not unique in a log several
  /// LogAppenders wrote).
  int64_t number = 0;
  /// Where the event starts in the file (bytes): unique, for messages about it.
  int64_t offset = 0;
  /// Receive time, microseconds since the Unix epoch.
  int64_t utime = 0;
  std::string channel;
  const uint8_t* data = nullptr;
  size_t size = 0;
};

/// What ReadLog found.
struct LogSummary {
  /// Events read whole.
  int64_t events = 0;
  /// Bytes at the end of the file that hold an incomplete last event (a logger stopped while
  /// writing it); 0 when the log ends cleanly. They are not passed on.
  int64_t truncated_bytes = 0;
};

/// Calls `handler` for every event of the LCM log at `path`, in file order. The format is
/// LCM's event log (lcm/eventlog.c): per event the magic, event number, time, channel length and
/// data length, big-endian, then the channel and the data. Throws std::runtime_error with one
/// line naming the file (and the byte offset) if it cannot be read, does not start with an event,
/// or holds a corrupt event header before its end (LCM itself would skip ahead silently); an
/// exception thrown by `handler` propagates.
LogSummary ReadLog(const std::string& path, const std::function<void(const LogEvent&)>& handler);

/// Decodes the event's bytes as `Message`; throws DecodeError naming the channel and the event
/// number if they do not decode.
template <typename Message>
Message DecodeLogEvent(const LogEvent& event) {
  Message message;
  if (message.decode(event.data, 0, static_cast<int>(event.size)) < 0) {
    throw DecodeError("cannot decode a " + std::string(Message::getTypeName()) + " on channel " +
                      event.channel + " (log event " + std::to_string(event.number) + ", " +
                      std::to_string(event.size) + " bytes)");
  }
  return message;
}

/// Writes an LCM log that lcm-logplayer and ReadLog read. The file is complete once the writer
/// is destroyed or Close() returns.
class LogWriter {
 public:
  /// Creates (or truncates) the log at `path`; throws std::runtime_error naming it on failure.
  explicit LogWriter(const std::string& path);
  ~LogWriter();
  LogWriter(const LogWriter&) = delete;
  LogWriter& operator=(const LogWriter&) = delete;

  /// Encodes `message` and appends it as an event on `channel` received at `utime`
  /// (microseconds since the Unix epoch). Throws std::runtime_error naming the file or channel.
  template <typename Message>
  void Write(const std::string& channel, const Message& message, int64_t utime) {
    std::vector<uint8_t> bytes(static_cast<size_t>(message.getEncodedSize()));
    if (message.encode(bytes.data(), 0, static_cast<int>(bytes.size())) < 0) {
      throw std::runtime_error("cannot encode message for channel " + channel);
    }
    WriteBytes(channel, bytes.data(), bytes.size(), utime);
  }

  /// Appends raw bytes as an event on `channel`. Throws std::runtime_error naming the file.
  void WriteBytes(const std::string& channel, const uint8_t* data, size_t size, int64_t utime);

  /// Hands what was written to the kernel (a reader sees it); throws std::runtime_error naming
  /// the file if that fails.
  void Flush();

  /// Flushes and closes the file; throws std::runtime_error naming it if that fails. Writing
  /// after Close() throws.
  void Close();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Appends events to an LCM log that several processes may write at once (the DataLoader workers
/// of one learner recording what they hand out): the file is opened with O_APPEND and every event
/// goes out in one write(2), so on a local file system events never interleave. Each appender
/// numbers its own events from 0. A log is read by ReadLog, lcm-logplayer and file:// buses.
class LogAppender {
 public:
  /// Opens `path` for appending, creating it (mode 0644) when missing; throws std::runtime_error
  /// naming it on failure. With a bus key file (`key_file`, see auth.h) every event is signed as
  /// a Bus would sign it, so the log replays under that key; "" signs nothing.
  explicit LogAppender(const std::string& path, const std::string& key_file = "");
  ~LogAppender();
  LogAppender(const LogAppender&) = delete;
  LogAppender& operator=(const LogAppender&) = delete;

  /// Appends `size` bytes as one event on `channel` received at `utime` (microseconds since the
  /// Unix epoch). Throws std::runtime_error naming the file and the system's reason. After a
  /// write that failed part way (a full disk) the log ends in a torn event, which readers skip
  /// only at the end of a file: the appender then refuses every later event.
  void AppendBytes(const std::string& channel, const uint8_t* data, size_t size, int64_t utime);

  /// The path given.
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  std::unique_ptr<MessageAuth> auth_;
  std::vector<uint8_t> sealed_;
  int fd_ = -1;
  int64_t next_event_ = 0;
  std::string failed_;  // why an earlier write failed part way; empty while none has
};

}  // namespace stackgen
