#include "bus/auth.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <stdexcept>
#include <unordered_map>

#include <openssl/core_names.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/rand.h>

#include "bus/udpm.h"

namespace stackgen {
namespace {

constexpr char kMagic[8] = {'S', 'G', 'A', 'U', 'T', 'H', '0', '3'};
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
  // O_NONBLOCK: opening a FIFO must not wait for a writer (it is refused just below)
  const int fd = open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
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

// the trailer's fields before the MAC: sender, counter, key id, bus
constexpr size_t kFieldBytes = 32;

// the MAC of channel, bytes and the trailer's first four fields, into `out`, from a copy of
// `keyed` (so that threads may compute at once)
void ComputeMac(EVP_MAC_CTX* keyed, const std::string& channel, const uint8_t* data, size_t size,
                const uint8_t* fields, uint8_t* out) {
  EVP_MAC_CTX* ctx = EVP_MAC_CTX_dup(keyed);
  uint8_t length[8];
  PutU64(channel.size(), length);
  size_t written = 0;
  const bool ok =
      ctx != nullptr && EVP_MAC_update(ctx, length, sizeof(length)) == 1 &&
      EVP_MAC_update(ctx, reinterpret_cast<const uint8_t*>(channel.data()), channel.size()) == 1 &&
      EVP_MAC_update(ctx, data, size) == 1 && EVP_MAC_update(ctx, fields, kFieldBytes) == 1 &&
      EVP_MAC_final(ctx, out, &written, kMacBytes) == 1 && written == kMacBytes;
  EVP_MAC_CTX_free(ctx);
  if (!ok) throw std::runtime_error("OpenSSL cannot compute an HMAC-SHA256");
}

// the base64 of `bytes` (OpenSSL), one line
std::string Base64(const unsigned char* bytes, int size) {
  std::string text(static_cast<size_t>(4 * ((size + 2) / 3)) + 1, '\0');
  const int length = EVP_EncodeBlock(reinterpret_cast<unsigned char*>(text.data()), bytes, size);
  text.resize(static_cast<size_t>(length));
  return text;
}

}  // namespace

std::string DefaultBusKeyFile() {
  const char* xdg = std::getenv("XDG_CONFIG_HOME");
  if (xdg != nullptr && xdg[0] == '/') return std::string(xdg) + "/stackgen/bus.key";
  const char* home = std::getenv("HOME");
  if (home != nullptr && home[0] != '\0') return std::string(home) + "/.config/stackgen/bus.key";
  throw std::runtime_error(
      "no bus key: neither XDG_CONFIG_HOME nor HOME is set, so this user's key has no place; "
      "pass --bus-key-file FILE (or set STACKGEN_BUS_KEY_FILE)");
}

bool MakeBusKeyFile(const std::string& path) {
  struct stat info {};
  if (lstat(path.c_str(), &info) == 0) return false;
  const auto fail = [&path](const std::string& what) {
    throw std::runtime_error("cannot make the bus key " + path + ": " + what + ": " +
                             strerror(errno));
  };
  // the folder (and its parents), private
  const size_t slash = path.rfind('/');
  if (slash != std::string::npos && slash > 0) {
    const std::string folder = path.substr(0, slash);
    for (size_t at = 1; at != std::string::npos;) {
      at = folder.find('/', at + 1);
      const std::string part = folder.substr(0, at);
      if (mkdir(part.c_str(), 0700) != 0 && errno != EEXIST) fail("mkdir " + part);
    }
  }
  // 32 random bytes, base64, under a temporary name, then linked into place: a key another
  // process made meanwhile wins, and nobody reads half a key
  unsigned char random[32];
  if (RAND_bytes(random, sizeof(random)) != 1) {
    throw std::runtime_error("cannot make the bus key " + path + ": OpenSSL has no random bytes");
  }
  const std::string text = Base64(random, sizeof(random)) + "\n";
  std::string temporary = path + ".XXXXXX";
  const int fd = mkstemp(temporary.data());  // mode 600
  if (fd < 0) fail("mkstemp");
  const bool written =
      write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size()) && fsync(fd) == 0;
  const int write_error = errno;
  close(fd);
  if (!written) {
    unlink(temporary.c_str());
    errno = write_error;
    fail("write");
  }
  const int linked = link(temporary.c_str(), path.c_str());
  const int link_error = errno;
  unlink(temporary.c_str());
  if (linked != 0 && link_error == EEXIST) return false;
  if (linked != 0) {
    errno = link_error;
    fail("link");
  }
  return true;
}

std::string ResolveBusKeyFile(const std::string& flag_value) {
  if (!flag_value.empty()) return flag_value;
  const char* from_env = std::getenv("STACKGEN_BUS_KEY_FILE");
  if (from_env != nullptr && from_env[0] != '\0') return from_env;
  const std::string path = DefaultBusKeyFile();
  if (MakeBusKeyFile(path)) {
    std::fprintf(stderr,
                 "%s: made a bus key at %s (mode 600): every process of this bus uses it; "
                 "copy it to other hosts, or point STACKGEN_BUS_KEY_FILE at a copy\n",
                 program_invocation_short_name, path.c_str());
  }
  return path;
}

std::string KeyIdText(uint64_t key_id) {
  char text[17];
  std::snprintf(text, sizeof(text), "%016llx", static_cast<unsigned long long>(key_id));
  return text;
}

bool ReadTrailer(const uint8_t* data, size_t size, Trailer* trailer) {
  if (!HasTrailer(data, size)) return false;
  const uint8_t* fields = data + size - kAuthTrailerBytes;
  trailer->sender = GetU64(fields);
  trailer->counter = GetU64(fields + 8);
  trailer->key_id = GetU64(fields + 16);
  trailer->bus = GetU64(fields + 24);
  return true;
}

uint64_t BusTag(const std::string& url) {
  if (url.rfind("udpm://", 0) != 0) return 0;
  const UdpmAddress address = ParseUdpmUrl(url);
  return (uint64_t{address.group} << 16) | address.port;
}

std::string BusTagText(uint64_t bus) {
  if (bus == 0) return "no bus (a log)";
  char text[32];
  std::snprintf(text, sizeof(text), "%u.%u.%u.%u:%u", static_cast<unsigned>((bus >> 40) & 255),
                static_cast<unsigned>((bus >> 32) & 255), static_cast<unsigned>((bus >> 24) & 255),
                static_cast<unsigned>((bus >> 16) & 255), static_cast<unsigned>(bus & 0xFFFF));
  return text;
}

int64_t UnixMicros() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

std::string RefusedSummary(const AuthCounters& counters) {
  return "refused " + std::to_string(counters.unsigned_messages) + " unsigned, " +
         std::to_string(counters.forged) + " forged or altered, " +
         std::to_string(counters.replayed) + " replayed, " + std::to_string(counters.relayed) +
         " relayed from another bus";
}

void KeyEvidence::Note(const MessageAuth& auth, const uint8_t* data, size_t size, bool verified) {
  Trailer trailer;
  const bool signed_message = ReadTrailer(data, size, &trailer);
  if (auth.keyed() ? verified : !signed_message) {
    ++taken;
    return;
  }
  ++mismatched;
  if (!signed_message) ++unsigned_messages;
  if (signed_message && trailer.key_id != auth.key_id()) other_key_id = trailer.key_id;
  if (signed_message && auth.keyed() && trailer.key_id == auth.key_id()) {
    ++forged;
    if (auth.liveness() && auth.bus() != 0 && trailer.bus != auth.bus()) ++relayed;
  }
}

void KeyEvidence::Add(const KeyEvidence& other) {
  taken += other.taken;
  mismatched += other.mismatched;
  unsigned_messages += other.unsigned_messages;
  forged += other.forged;
  relayed += other.relayed;
  if (other.other_key_id != 0) other_key_id = other.other_key_id;
}

std::string KeyEvidence::Mismatch(const MessageAuth& auth, const std::string& what) const {
  if (taken > 0 || mismatched == 0) return "";
  const std::string heard = what + " (" + std::to_string(mismatched) + " heard)";
  if (!auth.keyed()) {
    return heard + " are signed with a bus key (key id " + KeyIdText(other_key_id) +
           "), but this process runs with an open bus (--open-bus): give it the same key "
           "(--bus-key-file FILE or STACKGEN_BUS_KEY_FILE)";
  }
  const std::string ours =
      "this process's key " + auth.key_file() + " (key id " + KeyIdText(auth.key_id()) + ")";
  if (unsigned_messages * 2 > mismatched || (other_key_id == 0 && unsigned_messages > forged)) {
    return heard + " are not signed (their sender runs with --open-bus, or recorded them so): " +
           "give it " + ours + ", or open this process too (--open-bus)";
  }
  if (other_key_id == 0 && relayed * 2 > forged) {
    return heard + " are signed with " + ours + " for another bus (group and port): relayed " +
           "from another run's bus, or a recording played back onto this one (a consumer takes " +
           "a recording with --replay); no peer of this bus was heard";
  }
  if (other_key_id == 0) {
    return heard + " carry the key id of " + ours +
           " but fail its check: forged, or altered on the way; no peer of this key was heard";
  }
  return heard + " are signed with another bus key (key id " + KeyIdText(other_key_id) + ") than " +
         ours +
         ": give every process of the bus the same key file (--bus-key-file FILE or "
         "STACKGEN_BUS_KEY_FILE; by default each user's ~/.config/stackgen/bus.key)";
}

// what one sender has shown: its counters seen, and whether and when it answered
struct SenderState {
  ReplayWindow window;
  bool answered = false;
  uint64_t answer_counter = 0;  // its messages up to this one were signed before it answered
};

struct MessageAuth::Impl {
  std::string key_file;
  bool liveness = true;
  uint64_t bus = 0;
  // HMAC-SHA256 keyed once; each message works on a copy
  EVP_MAC* mac = nullptr;
  EVP_MAC_CTX* keyed = nullptr;
  uint64_t key_id = 0;
  uint64_t sender = 0;

  // what follows is shared by the threads
  mutable std::mutex mutex;
  uint64_t counter = 0;
  std::unordered_map<uint64_t, SenderState> senders;
  uint64_t uses = 0;
  int64_t answered = 0;
  AuthCounters counters;
  int64_t messages = 0;
  double seconds = 0;

  ~Impl() {
    EVP_MAC_CTX_free(keyed);
    EVP_MAC_free(mac);
  }

  // counts a refusal under `kind` and says why; returns -1
  int64_t Refuse(int64_t AuthCounters::*kind, const std::string& channel, const std::string& text,
                 std::string* why) {
    {
      const std::lock_guard<std::mutex> lock(mutex);
      ++(counters.*kind);
    }
    if (why != nullptr) *why = "refused a message on channel " + channel + ": " + text;
    return -1;
  }

  // the state of `id`, made when new; the least recently heard is forgotten beyond kMaxSenders.
  // With the mutex held.
  SenderState& StateOf(uint64_t id) {
    auto found = senders.find(id);
    if (found == senders.end()) {
      if (senders.size() >= kMaxSenders) {
        auto oldest = senders.begin();
        for (auto it = senders.begin(); it != senders.end(); ++it) {
          if (it->second.window.last_use < oldest->second.window.last_use) oldest = it;
        }
        senders.erase(oldest);
      }
      found = senders.emplace(id, SenderState{}).first;
    }
    found->second.window.last_use = ++uses;
    return found->second;
  }
};

MessageAuth::MessageAuth(const std::string& key_file, bool liveness, uint64_t bus)
    : impl_(std::make_unique<Impl>()) {
  impl_->key_file = key_file;
  impl_->liveness = liveness;
  impl_->bus = bus;
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
  // the key id: the first 8 bytes of the MAC of a fixed text
  EVP_MAC_CTX* ctx = EVP_MAC_CTX_dup(impl_->keyed);
  const std::string label = "stackgen bus key id";
  uint8_t id[kMacBytes];
  size_t written = 0;
  const bool ok =
      ctx != nullptr &&
      EVP_MAC_update(ctx, reinterpret_cast<const uint8_t*>(label.data()), label.size()) == 1 &&
      EVP_MAC_final(ctx, id, &written, kMacBytes) == 1 && written == kMacBytes;
  EVP_MAC_CTX_free(ctx);
  if (!ok) throw std::runtime_error("OpenSSL cannot compute an HMAC-SHA256");
  impl_->key_id = GetU64(id);
  do {
    if (RAND_bytes(reinterpret_cast<unsigned char*>(&impl_->sender), sizeof(impl_->sender)) != 1) {
      throw std::runtime_error("OpenSSL cannot draw a random sender id");
    }
  } while (impl_->sender == 0);  // 0 means "every process" in a liveness challenge
}

MessageAuth::~MessageAuth() = default;

bool MessageAuth::keyed() const { return impl_->keyed != nullptr; }

const std::string& MessageAuth::key_file() const { return impl_->key_file; }

uint64_t MessageAuth::key_id() const { return impl_->key_id; }

uint64_t MessageAuth::sender() const { return impl_->sender; }

bool MessageAuth::liveness() const { return impl_->liveness; }

uint64_t MessageAuth::bus() const { return impl_->bus; }

AuthCounters MessageAuth::counters() const {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->counters;
}

int64_t MessageAuth::messages() const {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->messages;
}

double MessageAuth::seconds() const {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->seconds;
}

// adds the time from its construction to its end to the seconds of `impl`, and counts one
// message when `count`
class MessageAuth::Timed {
 public:
  Timed(Impl* impl, bool count) : impl_(impl), count_(count), start_(Clock::now()) {}
  ~Timed() {
    const double seconds = std::chrono::duration<double>(Clock::now() - start_).count();
    const std::lock_guard<std::mutex> lock(impl_->mutex);
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

uint64_t MessageAuth::Seal(const std::string& channel, const uint8_t* data, size_t size,
                           std::vector<uint8_t>* sealed) {
  sealed->assign(data, data + size);
  if (!keyed()) return 0;
  const Timed timed(impl_.get(), true);
  sealed->resize(size + kAuthTrailerBytes);
  uint8_t* trailer = sealed->data() + size;
  uint64_t counter = 0;
  {
    const std::lock_guard<std::mutex> lock(impl_->mutex);
    counter = ++impl_->counter;
  }
  PutU64(impl_->sender, trailer);
  PutU64(counter, trailer + 8);
  PutU64(impl_->key_id, trailer + 16);
  PutU64(impl_->bus, trailer + 24);
  ComputeMac(impl_->keyed, channel, data, size, trailer, trailer + kFieldBytes);
  std::memcpy(trailer + kFieldBytes + kMacBytes, kMagic, 8);
  return counter;
}

int64_t MessageAuth::Open(const std::string& channel, const uint8_t* data, size_t size,
                          std::string* why) {
  if (Verify(channel, data, size, why) < 0) return -1;
  return Admit(channel, data, size, why);
}

int64_t MessageAuth::Verify(const std::string& channel, const uint8_t* data, size_t size,
                            std::string* why) {
  Trailer trailer;
  const bool signed_message = ReadTrailer(data, size, &trailer);
  if (!keyed()) {
    return static_cast<int64_t>(signed_message ? size - kAuthTrailerBytes : size);
  }
  const Timed timed(impl_.get(), true);
  if (!signed_message) {
    return impl_->Refuse(&AuthCounters::unsigned_messages, channel,
                         "it is not signed (its sender has no bus key: --open-bus; or this log "
                         "was recorded without one)",
                         why);
  }
  if (trailer.key_id != impl_->key_id) {
    return impl_->Refuse(&AuthCounters::forged, channel,
                         "it is signed with another bus key (key id " + KeyIdText(trailer.key_id) +
                             "; this process's " + impl_->key_file + " has key id " +
                             KeyIdText(impl_->key_id) + ")",
                         why);
  }
  // the MAC: nothing of an unauthenticated message is believed, its sender neither
  const size_t body = size - kAuthTrailerBytes;
  const uint8_t* fields = data + body;
  uint8_t expected[kMacBytes];
  ComputeMac(impl_->keyed, channel, data, body, fields, expected);
  if (CRYPTO_memcmp(expected, fields + kFieldBytes, kMacBytes) != 0) {
    return impl_->Refuse(&AuthCounters::forged, channel,
                         "its MAC does not match (forged or altered)", why);
  }
  // signed for this bus: not relayed from another group or port (a replay or a log may come
  // from anywhere)
  if (impl_->liveness && impl_->bus != 0 && trailer.bus != impl_->bus) {
    return impl_->Refuse(&AuthCounters::relayed, channel,
                         "it was signed for another bus (" + BusTagText(trailer.bus) +
                             "; this one is " + BusTagText(impl_->bus) +
                             "): relayed from another group or port, or a recording played "
                             "back here (a consumer takes a recording with --replay)",
                         why);
  }
  return static_cast<int64_t>(body);
}

int64_t MessageAuth::Admit(const std::string& channel, const uint8_t* data, size_t size,
                           std::string* why) {
  Trailer trailer;
  const bool signed_message = ReadTrailer(data, size, &trailer);
  if (!keyed()) {
    return static_cast<int64_t>(signed_message ? size - kAuthTrailerBytes : size);
  }
  if (!signed_message) {
    return impl_->Refuse(&AuthCounters::unsigned_messages, channel, "it is not signed", why);
  }
  std::string refusal;
  {
    const std::lock_guard<std::mutex> lock(impl_->mutex);
    SenderState& state = impl_->StateOf(trailer.sender);
    const bool self = trailer.sender == impl_->sender;
    if (impl_->liveness && !self && !state.answered) {
      refusal = "its sender (" + KeyIdText(trailer.sender) +
                ") has not answered this process's liveness check (a recording played back onto "
                "the bus?)";
    } else if (impl_->liveness && !self && trailer.counter <= state.answer_counter) {
      refusal = "its sender signed it before it answered this process's liveness check (sender " +
                KeyIdText(trailer.sender) + ", counter " + std::to_string(trailer.counter) +
                "): a recording played back onto the bus";
    } else if (!state.window.Accept(trailer.counter)) {
      refusal = "it was received before (sender " + KeyIdText(trailer.sender) + ", counter " +
                std::to_string(trailer.counter) + ")";
    }
  }
  if (!refusal.empty()) return impl_->Refuse(&AuthCounters::replayed, channel, refusal, why);
  return static_cast<int64_t>(size - kAuthTrailerBytes);
}

bool MessageAuth::Live(uint64_t sender) const {
  if (!impl_->liveness || sender == impl_->sender) return true;
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  const auto found = impl_->senders.find(sender);
  return found != impl_->senders.end() && found->second.answered;
}

void MessageAuth::Proven(uint64_t sender, uint64_t counter) {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  SenderState& state = impl_->StateOf(sender);
  // the first answer sets the floor: a later one (to a challenge still in flight) must not drop
  // what the sender signed in between
  if (state.answered) return;
  state.answered = true;
  state.answer_counter = counter;
  ++impl_->answered;
}

int64_t MessageAuth::answered() const {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->answered;
}

void MessageAuth::CountUnanswered() {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  ++impl_->counters.replayed;
}

}  // namespace stackgen
