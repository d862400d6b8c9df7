#include "bus/log.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <lcm/lcm-cpp.hpp>
#include <vector>

namespace stackgen {
namespace {

// the first four bytes of the file at `path`, big-endian; throws naming the file if they cannot
// be read.
// magic, event number, time, channel length, data length
constexpr int64_t kLogHeaderBytes = 4 + 8 + 8 + 4 + 4;
// channel names at least this long are taken as corruption (as lcm/eventlog.c does)
constexpr int64_t kMaxChannelLength = 1000;

// the big-endian unsigned number in `size` bytes at `bytes`
uint64_t BigEndian(const uint8_t* bytes, int size) {
  uint64_t value = 0;
  for (int k = 0; k < size; ++k) value = (value << 8) | bytes[k];
  return value;
}

uint32_t ReadFirstWord(const std::string& path) {
  std::error_code error;
  if (std::filesystem::is_directory(path, error)) {
    throw std::runtime_error(path + " is a folder, not an LCM log");
  }
  std::ifstream file(path, std::ios::binary);
  if (!file) throw std::runtime_error("cannot open " + path + ": " + std::strerror(errno));
  unsigned char bytes[4] = {0, 0, 0, 0};
  file.read(reinterpret_cast<char*>(bytes), 4);
  if (file.gcount() != 4) throw std::runtime_error(path + " is too short to be an LCM log");
  return (uint32_t{bytes[0]} << 24) | (uint32_t{bytes[1]} << 16) | (uint32_t{bytes[2]} << 8) |
         uint32_t{bytes[3]};
}

}  // namespace

bool IsLcmLog(const std::string& path) {
  try {
    return ReadFirstWord(path) == kLcmLogMagic;
  } catch (const std::runtime_error&) {
    return false;
  }
}

LogSummary ReadLog(const std::string& path, const std::function<void(const LogEvent&)>& handler) {
  // refuse anything that does not start like a log
  if (ReadFirstWord(path) != kLcmLogMagic) {
    throw std::runtime_error(path + " is not an LCM log (no event magic at its start)");
  }
  std::ifstream file(path, std::ios::binary);
  if (!file) throw std::runtime_error("cannot open " + path + ": " + std::strerror(errno));
  file.seekg(0, std::ios::end);
  const int64_t file_size = static_cast<int64_t>(file.tellg());
  file.seekg(0, std::ios::beg);

  // event by event; LCM's reader resynchronises on the next magic after a bad header and says so
  // on stderr, so the header is parsed here to report a corrupt log as one error
  LogSummary summary;
  LogEvent event;
  std::vector<uint8_t> buffer;
  int64_t offset = 0;
  while (offset < file_size) {
    const auto fail = [&](const std::string& what) {
      return std::runtime_error(path + ": corrupt LCM log at byte " + std::to_string(offset) +
                                " (event " + std::to_string(summary.events) + "): " + what);
    };
    uint8_t header[kLogHeaderBytes];
    if (file_size - offset < kLogHeaderBytes) break;
    file.read(reinterpret_cast<char*>(header), kLogHeaderBytes);
    if (!file) throw std::runtime_error("cannot read " + path);
    if (BigEndian(header, 4) != kLcmLogMagic) throw fail("no event magic");
    event.number = static_cast<int64_t>(BigEndian(header + 4, 8));
    event.utime = static_cast<int64_t>(BigEndian(header + 12, 8));
    const int64_t channel_length = static_cast<int32_t>(BigEndian(header + 20, 4));
    const int64_t data_length = static_cast<int32_t>(BigEndian(header + 24, 4));
    if (channel_length <= 0 || channel_length >= kMaxChannelLength) {
      throw fail("channel length " + std::to_string(channel_length));
    }
    if (data_length < 0) throw fail("data length " + std::to_string(data_length));
    if (file_size - offset - kLogHeaderBytes < channel_length + data_length) break;

    // the channel and the data
    event.channel.resize(static_cast<size_t>(channel_length));
    file.read(event.channel.data(), channel_length);
    buffer.resize(static_cast<size_t>(data_length));
    file.read(reinterpret_cast<char*>(buffer.data()), data_length);
    if (!file) throw std::runtime_error("cannot read " + path);
    event.data = buffer.data();
    event.size = buffer.size();
    event.offset = offset;
    offset += kLogHeaderBytes + channel_length + data_length;
    ++summary.events;
    handler(event);
  }
  summary.truncated_bytes = file_size - offset;
  return summary;
}

struct LogWriter::Impl {
  std::string path;
  std::unique_ptr<lcm::LogFile> log;
};

LogWriter::LogWriter(const std::string& path) : impl_(std::make_unique<Impl>()) {
  impl_->path = path;
  impl_->log = std::make_unique<lcm::LogFile>(path, "w");
  if (!impl_->log->good()) {
    throw std::runtime_error("cannot create " + path + ": " + std::strerror(errno));
  }
}

LogWriter::~LogWriter() {
  try {
    Close();
  } catch (const std::exception&) {
    // a destructor must not throw; Close() reports the error to callers that want it
  }
}

void LogWriter::WriteBytes(const std::string& channel, const uint8_t* data, size_t size,
                           int64_t utime) {
  if (!impl_->log) throw std::runtime_error("log " + impl_->path + " is already closed");
  // LCM numbers the events itself
  lcm::LogEvent event;
  event.eventnum = 0;
  event.timestamp = utime;
  event.channel = channel;
  event.datalen = static_cast<int32_t>(size);
  event.data = const_cast<uint8_t*>(data);
  if (impl_->log->writeEvent(&event) != 0) {
    throw std::runtime_error("cannot write to " + impl_->path + " (channel " + channel + ")");
  }
}

void LogWriter::Flush() {
  if (!impl_->log) throw std::runtime_error("log " + impl_->path + " is already closed");
  if (std::fflush(impl_->log->getFilePtr()) != 0) {
    throw std::runtime_error("cannot write " + impl_->path + ": " + std::strerror(errno));
  }
}

void LogWriter::Close() {
  if (!impl_->log) return;
  // flush before LCM closes the file, so a full disk is reported
  const bool flushed =
      std::fflush(impl_->log->getFilePtr()) == 0 && std::ferror(impl_->log->getFilePtr()) == 0;
  impl_->log.reset();
  if (!flushed) throw std::runtime_error("cannot write " + impl_->path);
}

LogAppender::LogAppender(const std::string& path, const std::string& key_file)
    : path_(path), auth_(std::make_unique<MessageAuth>(key_file, false)) {
  fd_ = open(path.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd_ < 0) throw std::runtime_error("cannot open " + path + ": " + std::strerror(errno));
}

LogAppender::~LogAppender() {
  if (fd_ >= 0) close(fd_);
}

void LogAppender::AppendBytes(const std::string& channel, const uint8_t* data, size_t size,
                              int64_t utime) {
  if (auth_->keyed()) {
    auth_->Seal(channel, data, size, &sealed_);
    data = sealed_.data();
    size = sealed_.size();
  }
  if (channel.empty() || static_cast<int64_t>(channel.size()) >= kMaxChannelLength ||
      size > static_cast<size_t>(INT32_MAX)) {
    throw std::runtime_error("cannot append an event of " + std::to_string(size) +
                             " bytes on channel \"" + channel + "\" to " + path_);
  }
  if (!failed_.empty()) {
    throw std::runtime_error("cannot append to " + path_ + ": an earlier event was cut short (" +
                             failed_ + ")");
  }
  // the whole event in one buffer: header (big-endian), channel, data
  std::vector<uint8_t> event(static_cast<size_t>(kLogHeaderBytes) + channel.size() + size);
  const auto put = [&event](size_t offset, uint64_t value, int bytes) {
    for (int k = 0; k < bytes; ++k) {
      event[offset + k] = static_cast<uint8_t>(value >> (8 * (bytes - 1 - k)));
    }
  };
  put(0, kLcmLogMagic, 4);
  put(4, static_cast<uint64_t>(next_event_), 8);
  put(12, static_cast<uint64_t>(utime), 8);
  put(20, channel.size(), 4);
  put(24, size, 4);
  std::copy(channel.begin(), channel.end(), event.begin() + kLogHeaderBytes);
  if (size > 0) std::copy(data, data + size, event.begin() + kLogHeaderBytes + channel.size());
  // one write: with O_APPEND the kernel places it whole at the end of the file
  const ssize_t written = write(fd_, event.data(), event.size());
  if (written != static_cast<ssize_t>(event.size())) {
    const std::string why = written < 0 ? std::strerror(errno) : "short write";
    // a short write leaves a torn last event, which readers skip at the end of the file only:
    // nothing may follow it
    if (written > 0) failed_ = why;
    throw std::runtime_error("cannot append to " + path_ + ": " + why);
  }
  ++next_event_;
}

}  // namespace stackgen
