#include "bus/auth.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <stdexcept>
#include <unordered_map>

#include <openssl/core_names.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/rand.h>

namespace stackgen {
namespace {

constexpr char kMagic[8] = {'S', 'G', 'A', 'U', 'T', 'H', '0', '1'};
constexpr size_t kMacBytes = 32;
// counters remembered per sender, and senders remembered
constexpr uint64_t kReplayWindow = 1024;
constexpr size_t kMaxSenders = 4096;

void PutU64(uint64_t value, uint8_t* out) {
  for (int i = 7; i >= 0; --i, value >>= 8) out[i] = static_cast<uint8_t>(value);
}

uint64_t GetU64(const uint8_t* in) {
  uint64_t value = 0;
  for (int i = 0; i < 8; ++i) value = (value << 8) | in[i];
  return value;
}

bool HasTrailer(const uint8_t* data, size_t size) {
  return size >= kAuthTrailerBytes && std::memcmp(data + size - 8, kMagic, 8) == 0;
}

// the key file's bytes, checked; throws naming the file
std::string ReadKeyFile(const std::string& path) {
  const std::string what = "bus key file " + path;
  const int fd = open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw std::runtime_error("cannot open " + what + ": " + strerror(errno));
  struct stat info {};
  if (fstat(fd, &info) != 0 || !S_ISREG(info.st_mode)) {
    close(fd);
    throw std::runtime_error(what + " is not a regular file");
  }
  if ((info.st_mode & (S_IROTH | S_IWOTH)) != 0) {
    close(fd);
    char mode[8];
    std::snprintf(mode, sizeof(mode), "%04o", static_cast<unsigned>(info.st_mode & 07777));
    throw std::runtime_error(what + " can be read or written by other users (mode " + mode +
                             "); chmod 600 it");
  }
  if (info.st_size > 65536) {
    close(fd);
    throw std::runtime_error(what + " is too large (" + std::to_string(info.st_size) +
                             " bytes; a key is 32 to 65536 bytes)");
  }
  std::string bytes(static_cast<size_t>(info.st_size), '\0');
  size_t got = 0;
  while (got < bytes.size()) {
    const ssize_t n = read(fd, bytes.data() + got, bytes.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int error = errno;
      close(fd);
      throw std::runtime_error("cannot read " + what + ": " +
                               (n < 0 ? strerror(error) : "it shrank while read"));
    }
    got += static_cast<size_t>(n);
  }
  close(fd);
  while (!bytes.empty() && std::strchr(" \t\r\n", bytes.back()) != nullptr) bytes.pop_back();
  if (bytes.size() < kMinBusKeyBytes) {
    throw std::runtime_error(what + " holds " + std::to_string(bytes.size()) +
                             " bytes; a key needs at least 32 (make one with `head -c 32 "
                             "/dev/urandom | base64 > FILE && chmod 600 FILE`)");
  }
  return bytes;
}

// which counters of one sender were seen: the highest, and a ring of the kReplayWindow newest
struct ReplayWindow {
  uint64_t highest = 0;
  std::array<uint64_t, kReplayWindow / 64> seen{};
  uint64_t last_use = 0;

  bool Test(uint64_t counter) const {
    const uint64_t bit = counter % kReplayWindow;
    return ((seen[bit / 64] >> (bit % 64)) & 1) != 0;
  }
  void Set(uint64_t counter, bool value) {
    const uint64_t bit = counter % kReplayWindow;
    if (value) {
      seen[bit / 64] |= uint64_t{1} << (bit % 64);
    } else {
      seen[bit / 64] &= ~(uint64_t{1} << (bit % 64));
    }
  }
  // true when `counter` is new (then it is marked seen)
  bool Accept(uint64_t counter) {
    if (counter > highest) {
      // forget the counters the window slides past
      if (counter - highest >= kReplayWindow) {
        seen.fill(0);
      } else {
        for (uint64_t c = highest + 1; c < counter; ++c) Set(c, false);
      }
      highest = counter;
      Set(counter, true);
      return true;
    }
    if (highest - counter >= kReplayWindow || Test(counter)) return false;
    Set(counter, true);
    return true;
  }
};

}  // namespace

std::string ResolveBusKeyFile(const std::string& flag_value) {
  if (!flag_value.empty()) return flag_value;
  const char* from_env = std::getenv("STACKGEN_BUS_KEY_FILE");
  if (from_env != nullptr && from_env[0] != '\0') return from_env;
  return "";
}

int64_t UnixMicros() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

std::string RefusedSummary(const AuthCounters& counters) {
  return "refused " + std::to_string(counters.unsigned_messages) + " unsigned, " +
         std::to_string(counters.forged) + " forged or altered, " +
         std::to_string(counters.replayed) + " replayed";
}

struct MessageAuth::Impl {
  std::string key_file;
  bool live = true;
  // HMAC-SHA256 keyed once; each message works on a copy
  EVP_MAC* mac = nullptr;
  EVP_MAC_CTX* keyed = nullptr;
  uint64_t sender = 0;
  uint64_t counter = 0;
  std::unordered_map<uint64_t, ReplayWindow> senders;
  uint64_t uses = 0;
  // what Verify (on a receiving thread) and the rest share
  mutable std::mutex stats_mutex;
  AuthCounters counters;
  int64_t messages = 0;
  double seconds = 0;

  // counts a refusal under `kind` and says why; returns -1
  int64_t Refuse(int64_t AuthCounters::*kind, const std::string& channel, const std::string& text,
                 std::string* why) {
    {
      const std::lock_guard<std::mutex> lock(stats_mutex);
      ++(counters.*kind);
    }
    if (why != nullptr) *why = "refused a message on channel " + channel + ": " + text;
    return -1;
  }

  ~Impl() {
    EVP_MAC_CTX_free(keyed);
    EVP_MAC_free(mac);
  }

  // the MAC of channel, bytes and the trailer's first three fields, into `out`
  void Compute(const std::string& channel, const uint8_t* data, size_t size, const uint8_t* fields,
               uint8_t* out) const {
    EVP_MAC_CTX* ctx = EVP_MAC_CTX_dup(keyed);
    uint8_t length[8];
    PutU64(channel.size(), length);
    size_t written = 0;
    const bool ok = ctx != nullptr && EVP_MAC_update(ctx, length, sizeof(length)) == 1 &&
                    EVP_MAC_update(ctx, reinterpret_cast<const uint8_t*>(channel.data()),
                                   channel.size()) == 1 &&
                    EVP_MAC_update(ctx, data, size) == 1 && EVP_MAC_update(ctx, fields, 24) == 1 &&
                    EVP_MAC_final(ctx, out, &written, kMacBytes) == 1 && written == kMacBytes;
    EVP_MAC_CTX_free(ctx);
    if (!ok) throw std::runtime_error("OpenSSL cannot compute an HMAC-SHA256");
  }
};

MessageAuth::MessageAuth(const std::string& key_file, bool live) : impl_(std::make_unique<Impl>()) {
  impl_->key_file = key_file;
  impl_->live = live;
  if (key_file.empty()) return;
  const std::string key = ReadKeyFile(key_file);
  impl_->mac = EVP_MAC_fetch(nullptr, "HMAC", nullptr);
  impl_->keyed = impl_->mac != nullptr ? EVP_MAC_CTX_new(impl_->mac) : nullptr;
  char digest[] = "SHA256";
  const OSSL_PARAM params[] = {OSSL_PARAM_construct_utf8_string(OSSL_MAC_PARAM_DIGEST, digest, 0),
                               OSSL_PARAM_END};
  if (impl_->keyed == nullptr ||
      EVP_MAC_init(impl_->keyed, reinterpret_cast<const uint8_t*>(key.data()), key.size(),
                   params) != 1) {
    throw std::runtime_error("OpenSSL has no HMAC-SHA256 to use with bus key file " + key_file);
  }
  if (RAND_bytes(reinterpret_cast<unsigned char*>(&impl_->sender), sizeof(impl_->sender)) != 1) {
    throw std::runtime_error("OpenSSL cannot draw a random sender id");
  }
}

MessageAuth::~MessageAuth() = default;

bool MessageAuth::keyed() const { return impl_->keyed != nullptr; }

const std::string& MessageAuth::key_file() const { return impl_->key_file; }

AuthCounters MessageAuth::counters() const {
  const std::lock_guard<std::mutex> lock(impl_->stats_mutex);
  return impl_->counters;
}

int64_t MessageAuth::messages() const {
  const std::lock_guard<std::mutex> lock(impl_->stats_mutex);
  return impl_->messages;
}

double MessageAuth::seconds() const {
  const std::lock_guard<std::mutex> lock(impl_->stats_mutex);
  return impl_->seconds;
}

// adds the time from its construction to its end to the seconds of `impl`, and counts one
// message when `count`
class MessageAuth::Timed {
 public:
  Timed(Impl* impl, bool count) : impl_(impl), count_(count), start_(Clock::now()) {}
  ~Timed() {
    const double seconds = std::chrono::duration<double>(Clock::now() - start_).count();
    const std::lock_guard<std::mutex> lock(impl_->stats_mutex);
    impl_->seconds += seconds;
    if (count_) ++impl_->messages;
  }
  Timed(const Timed&) = delete;
  Timed& operator=(const Timed&) = delete;

 private:
  using Clock = std::chrono::steady_clock;
  Impl* impl_;
  bool count_;
  Clock::time_point start_;
};

void MessageAuth::Seal(const std::string& channel, const uint8_t* data, size_t size,
                       std::vector<uint8_t>* sealed) {
  sealed->assign(data, data + size);
  if (!keyed()) return;
  const Timed timed(impl_.get(), true);
  sealed->resize(size + kAuthTrailerBytes);
  uint8_t* trailer = sealed->data() + size;
  PutU64(impl_->sender, trailer);
  PutU64(++impl_->counter, trailer + 8);
  PutU64(static_cast<uint64_t>(UnixMicros()), trailer + 16);
  impl_->Compute(channel, data, size, trailer, trailer + 24);
  std::memcpy(trailer + 56, kMagic, 8);
}

int64_t MessageAuth::Open(const std::string& channel, const uint8_t* data, size_t size,
                          int64_t now_us, std::string* why) {
  if (Verify(channel, data, size, why) < 0) return -1;
  return Admit(channel, data, size, now_us, why);
}

int64_t MessageAuth::Verify(const std::string& channel, const uint8_t* data, size_t size,
                            std::string* why) {
  const bool signed_message = HasTrailer(data, size);
  if (!keyed()) {
    return static_cast<int64_t>(signed_message ? size - kAuthTrailerBytes : size);
  }
  const Timed timed(impl_.get(), true);
  if (!signed_message) {
    return impl_->Refuse(&AuthCounters::unsigned_messages, channel,
                         "it is not signed (its sender has no bus key, or this log was recorded "
                         "without one)",
                         why);
  }
  // the MAC first: nothing of an unauthenticated message is believed, its sender neither
  const size_t body = size - kAuthTrailerBytes;
  const uint8_t* trailer = data + body;
  uint8_t expected[kMacBytes];
  impl_->Compute(channel, data, body, trailer, expected);
  if (CRYPTO_memcmp(expected, trailer + 24, kMacBytes) != 0) {
    return impl_->Refuse(&AuthCounters::forged, channel,
                         "its MAC does not match (forged, altered, or signed with another key "
                         "than " +
                             impl_->key_file + ")",
                         why);
  }
  return static_cast<int64_t>(body);
}

int64_t MessageAuth::Admit(const std::string& channel, const uint8_t* data, size_t size,
                           int64_t now_us, std::string* why) {
  const bool signed_message = HasTrailer(data, size);
  if (!keyed()) {
    return static_cast<int64_t>(signed_message ? size - kAuthTrailerBytes : size);
  }
  if (!signed_message) {
    return impl_->Refuse(&AuthCounters::unsigned_messages, channel, "it is not signed", why);
  }
  const Timed timed(impl_.get(), false);
  const size_t body = size - kAuthTrailerBytes;
  const uint8_t* trailer = data + body;
  const uint64_t sender = GetU64(trailer);
  const uint64_t counter = GetU64(trailer + 8);
  const int64_t stamped = static_cast<int64_t>(GetU64(trailer + 16));
  if (impl_->live) {
    const double age_s = static_cast<double>(now_us - stamped) * 1e-6;
    if (age_s > kMaxMessageAgeS || age_s < -kMaxMessageAgeS) {
      return impl_->Refuse(&AuthCounters::replayed, channel,
                           "it was sent " + std::to_string(static_cast<int64_t>(age_s)) +
                               " s ago (a replay, or clocks that differ by more than 60 s)",
                           why);
    }
  }
  // the sender's window; the least recently heard sender is forgotten beyond kMaxSenders
  auto found = impl_->senders.find(sender);
  if (found == impl_->senders.end()) {
    if (impl_->senders.size() >= kMaxSenders) {
      auto oldest = impl_->senders.begin();
      for (auto it = impl_->senders.begin(); it != impl_->senders.end(); ++it) {
        if (it->second.last_use < oldest->second.last_use) oldest = it;
      }
      impl_->senders.erase(oldest);
    }
    found = impl_->senders.emplace(sender, ReplayWindow{}).first;
  }
  found->second.last_use = ++impl_->uses;
  if (!found->second.Accept(counter)) {
    return impl_->Refuse(&AuthCounters::replayed, channel,
                         "it was received before (sender " + std::to_string(sender) +
                             ", counter " + std::to_string(counter) + ")",
                         why);
  }
  return static_cast<int64_t>(body);
}

}  // namespace stackgen
