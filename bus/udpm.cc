#include "bus/udpm.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <map>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

namespace stackgen {
namespace {

constexpr uint32_t kMagicShort = 0x4c433032;  // "LC02"
constexpr uint32_t kMagicLong = 0x4c433033;   // "LC03"
constexpr size_t kShortHeaderBytes = 8;
constexpr size_t kLongHeaderBytes = 20;
// LCM_MAX_CHANNEL_NAME_LENGTH
constexpr size_t kMaxChannelBytes = 63;
// the largest UDP payload over IPv4 is 65507 bytes; one more shows a datagram cut short
constexpr size_t kDatagramBuffer = 65536;
// what reassembly counts for bookkeeping beside the bytes heard: a message in reassembly (its
// record, channel and place in the table; plus a bit per fragment), and each fragment heard (its
// node and buffer header, and the allocator's overhead); more than they take here
constexpr size_t kPartialBytes = 512;
constexpr size_t kFragmentBytes = 128;

// what a whole message of `size` bytes in `fragments` fragments holds in reassembly
size_t MessageCost(uint32_t size, uint16_t fragments) {
  return kPartialBytes + fragments / 8 + size + size_t{fragments} * kFragmentBytes;
}

double SteadySeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

uint32_t GetU32(const uint8_t* in) {
  return (uint32_t{in[0]} << 24) | (uint32_t{in[1]} << 16) | (uint32_t{in[2]} << 8) | in[3];
}

uint16_t GetU16(const uint8_t* in) { return static_cast<uint16_t>((in[0] << 8) | in[1]); }

// the channel at data[0, size): 1..63 bytes and a NUL within the datagram; its length, or -1
int64_t ChannelLength(const uint8_t* data, size_t size) {
  const size_t limit = std::min(size, kMaxChannelBytes + 1);
  const void* nul = std::memchr(data, '\0', limit);
  if (nul == nullptr) return -1;
  const size_t length = static_cast<size_t>(static_cast<const uint8_t*>(nul) - data);
  return length == 0 ? -1 : static_cast<int64_t>(length);
}

std::string Errno(const std::string& call) { return call + ": " + std::strerror(errno); }

}  // namespace

UdpmAddress ParseUdpmUrl(const std::string& url) {
  const std::string scheme = "udpm://";
  if (url.rfind(scheme, 0) != 0) throw std::runtime_error("not a udpm:// URL: " + url);
  const size_t query = url.find('?', scheme.size());
  const std::string where = url.substr(scheme.size(), query - scheme.size());
  const size_t colon = where.find(':');
  const std::string group = where.substr(0, colon);
  UdpmAddress address;
  if (colon != std::string::npos) {
    const std::string port = where.substr(colon + 1);
    char* end = nullptr;
    const long value = std::strtol(port.c_str(), &end, 10);
    if (port.empty() || *end != '\0' || value <= 0 || value > 65535) {
      throw std::runtime_error("bad port in LCM URL " + url);
    }
    address.port = static_cast<uint16_t>(value);
  }
  in_addr parsed{};
  if (inet_pton(AF_INET, group.c_str(), &parsed) != 1 || !IN_MULTICAST(ntohl(parsed.s_addr))) {
    throw std::runtime_error("LCM URL " + url + " does not name an IPv4 multicast group");
  }
  address.group = ntohl(parsed.s_addr);
  // the options LCM reads; the others are LCM's to warn about when it opens the URL
  for (size_t at = query; at != std::string::npos && at + 1 < url.size();) {
    const size_t next = url.find('&', at + 1);
    const std::string option = url.substr(at + 1, next == std::string::npos ? next : next - at - 1);
    at = next;
    if (option.rfind("recv_buf_size=", 0) != 0) continue;
    const std::string text = option.substr(14);
    char* end = nullptr;
    const long value = std::strtol(text.c_str(), &end, 10);
    if (text.empty() || *end != '\0' || value < 0 || value > (1L << 30)) {
      throw std::runtime_error("bad recv_buf_size in LCM URL " + url + " (bytes, 0..1073741824)");
    }
    address.recv_buf_size = static_cast<int>(value);
  }
  return address;
}

std::string ReceiveSummary(const UdpmCounters& counters) {
  return "received " + std::to_string(counters.datagrams) +
         " datagrams: " + std::to_string(counters.malformed) + " malformed, " +
         std::to_string(counters.abandoned) + " messages given up incomplete, " +
         std::to_string(counters.queue_full) + " dropped for a full queue";
}

// ---------------------------------------------------------------------------------------------
// UdpmReassembler

struct UdpmReassembler::Impl {
  // one message in reassembly: the fragments heard, each kept as it came (nothing is allocated
  // for bytes that did not arrive; the message is put together when its last fragment comes)
  struct Partial {
    std::string channel;
    uint32_t seqno = 0;
    uint32_t size = 0;
    uint16_t fragments = 0;
    std::vector<bool> heard;  // by fragment number
    std::map<uint32_t, std::vector<uint8_t>> pieces;  // by offset
    uint64_t bytes_heard = 0;
    size_t cost = 0;  // what it holds, bookkeeping included (kPartialBytes, kFragmentBytes)
    uint64_t last_use = 0;
    double last_heard_s = 0;
  };

  UdpmLimits limits;
  std::function<bool(const std::string&)> wanted;
  std::unordered_map<uint64_t, Partial> partials;  // by sender
  size_t partial_bytes = 0;
  uint64_t uses = 0;
  UdpmCounters counters;

  void Forget(std::unordered_map<uint64_t, Partial>::iterator it) {
    partial_bytes -= it->second.cost;
    partials.erase(it);
  }

  // the message of `sender` is given up
  void Abandon(uint64_t sender) {
    const auto found = partials.find(sender);
    if (found == partials.end()) return;
    ++counters.abandoned;
    Forget(found);
  }

  // a datagram that breaks the rules; the message of its sender in reassembly goes with it
  bool Malformed(uint64_t sender) {
    ++counters.malformed;
    const auto found = partials.find(sender);
    if (found != partials.end()) Forget(found);
    return false;
  }

  // room for `bytes` more (and, with `another`, one more message) in reassembly, the least
  // recent other than `keep`'s giving way
  void MakeRoom(size_t bytes, bool another, uint64_t keep) {
    while (partial_bytes + bytes > limits.max_partial_bytes ||
           (another && static_cast<int>(partials.size()) >= limits.max_partials)) {
      auto oldest = partials.end();
      for (auto it = partials.begin(); it != partials.end(); ++it) {
        if (it->first == keep) continue;
        if (oldest == partials.end() || it->second.last_use < oldest->second.last_use) oldest = it;
      }
      if (oldest == partials.end()) return;
      ++counters.abandoned;
      Forget(oldest);
    }
  }

  // messages that heard no fragment for partial_timeout_s are given up (Add looks every quarter
  // of it)
  double swept_s = 0;
  void Expire(double now_s) {
    swept_s = now_s;
    for (auto it = partials.begin(); it != partials.end();) {
      if (now_s - it->second.last_heard_s >= limits.partial_timeout_s) {
        ++counters.abandoned;
        partial_bytes -= it->second.cost;
        it = partials.erase(it);
      } else {
        ++it;
      }
    }
  }

  bool Short(uint64_t sender, const uint8_t* data, size_t size, UdpmMessage* message) {
    const int64_t length = ChannelLength(data + kShortHeaderBytes, size - kShortHeaderBytes);
    if (length < 0) return Malformed(sender);
    std::string channel(reinterpret_cast<const char*>(data + kShortHeaderBytes),
                        static_cast<size_t>(length));
    if (!wanted(channel)) return false;
    const size_t start = kShortHeaderBytes + static_cast<size_t>(length) + 1;
    message->channel = std::move(channel);
    message->size = size - start;
    message->data.reset(new uint8_t[std::max<size_t>(1, message->size)]);
    std::memcpy(message->data.get(), data + start, message->size);
    ++counters.messages;
    return true;
  }

  bool Fragment(uint64_t sender, const uint8_t* data, size_t size, double now_s,
                UdpmMessage* message) {
    if (size < kLongHeaderBytes) return Malformed(sender);
    const uint32_t seqno = GetU32(data + 4);
    const uint32_t msg_size = GetU32(data + 8);
    const uint32_t offset = GetU32(data + 12);
    const uint16_t number = GetU16(data + 16);
    const uint16_t fragments = GetU16(data + 18);
    if (msg_size == 0 || msg_size > limits.max_message_bytes || fragments == 0 ||
        number >= fragments) {
      return Malformed(sender);
    }

    // another message of this sender ends the one in reassembly
    auto found = partials.find(sender);
    if (found != partials.end() &&
        (found->second.seqno != seqno || found->second.size != msg_size ||
         found->second.fragments != fragments)) {
      Abandon(sender);
      found = partials.end();
    }

    // fragment 0 begins a message: its channel first
    const uint8_t* bytes = data + kLongHeaderBytes;
    size_t length = size - kLongHeaderBytes;
    if (number == 0) {
      const int64_t channel_length = ChannelLength(bytes, length);
      if (channel_length < 0 || offset != 0) return Malformed(sender);
      if (found != partials.end()) return Malformed(sender);  // fragment 0 again
      std::string channel(reinterpret_cast<const char*>(bytes),
                          static_cast<size_t>(channel_length));
      if (!wanted(channel)) return false;
      bytes += channel_length + 1;
      length -= static_cast<size_t>(channel_length) + 1;
      // what the whole message would hold: more than reassembly may, and it is never begun
      if (MessageCost(msg_size, fragments) > limits.max_partial_bytes) return Malformed(sender);
      const size_t cost = kPartialBytes + fragments / 8;
      MakeRoom(cost, true, sender);
      Partial partial;
      partial.channel = std::move(channel);
      partial.seqno = seqno;
      partial.size = msg_size;
      partial.fragments = fragments;
      partial.heard.assign(fragments, false);
      partial.cost = cost;
      found = partials.emplace(sender, std::move(partial)).first;
      partial_bytes += cost;
    } else if (found == partials.end()) {
      return false;  // its fragment 0 was not heard: nothing to add it to
    }

    // the fragment's place: inside the message, once, over no other
    Partial& partial = found->second;
    const uint64_t end = uint64_t{offset} + length;
    if (length == 0 || end > partial.size || partial.heard[number]) {
      return Malformed(sender);
    }
    const auto after = partial.pieces.lower_bound(offset);
    if (after != partial.pieces.end() && after->first < end) return Malformed(sender);
    if (after != partial.pieces.begin() &&
        std::prev(after)->first + std::prev(after)->second.size() > offset) {
      return Malformed(sender);
    }
    const size_t cost = length + kFragmentBytes;
    MakeRoom(cost, false, sender);
    partial.pieces.emplace_hint(after, offset, std::vector<uint8_t>(bytes, bytes + length));
    partial.heard[number] = true;
    partial.bytes_heard += length;
    partial.cost += cost;
    partial_bytes += cost;
    partial.last_use = ++uses;
    partial.last_heard_s = now_s;
    if (partial.pieces.size() < partial.fragments) return false;

    // every fragment heard: complete when they cover the message
    if (partial.bytes_heard != partial.size) return Malformed(sender);
    message->channel = std::move(partial.channel);
    message->data.reset(new uint8_t[partial.size]);
    for (const auto& [at, piece] : partial.pieces) {
      std::memcpy(message->data.get() + at, piece.data(), piece.size());
    }
    message->size = partial.size;
    Forget(found);
    ++counters.messages;
    return true;
  }
};

UdpmReassembler::UdpmReassembler(const UdpmLimits& limits,
                                 std::function<bool(const std::string&)> wanted)
    : impl_(std::make_unique<Impl>()) {
  impl_->limits = limits;
  impl_->wanted = std::move(wanted);
}

UdpmReassembler::~UdpmReassembler() = default;

bool UdpmReassembler::Add(uint64_t sender, const uint8_t* data, size_t size, UdpmMessage* message) {
  return Add(sender, data, size, SteadySeconds(), message);
}

bool UdpmReassembler::Add(uint64_t sender, const uint8_t* data, size_t size, double now_s,
                          UdpmMessage* message) {
  Impl& impl = *impl_;
  ++impl.counters.datagrams;
  if (now_s - impl.swept_s >= impl.limits.partial_timeout_s / 4) impl.Expire(now_s);
  if (size < kShortHeaderBytes || size >= kDatagramBuffer) return impl.Malformed(sender);
  const uint32_t magic = GetU32(data);
  if (magic == kMagicShort) return impl.Short(sender, data, size, message);
  if (magic == kMagicLong) return impl.Fragment(sender, data, size, now_s, message);
  return impl.Malformed(sender);
}

void UdpmReassembler::Expire() { Expire(SteadySeconds()); }

void UdpmReassembler::Expire(double now_s) { impl_->Expire(now_s); }

size_t UdpmReassembler::partial_bytes() const { return impl_->partial_bytes; }

int UdpmReassembler::partials() const { return static_cast<int>(impl_->partials.size()); }

const UdpmCounters& UdpmReassembler::counters() const { return impl_->counters; }

// ---------------------------------------------------------------------------------------------
// UdpmReceiver

struct UdpmReceiver::Impl {
  UdpmLimits limits;
  Admit admit;
  int socket_fd = -1;
  int wake_fd = -1;  // the thread says "queued" here
  int stop_fd = -1;  // the destructor says "stop" here

  mutable std::mutex mutex;             // guards what follows
  std::map<std::string, int> capacity;  // by channel
  std::function<bool(const std::string&)> matches;  // SubscribeMatching
  int matched_capacity = 0;
  size_t matched_channels = 0;
  std::map<std::string, int> queued;    // by channel
  std::deque<UdpmMessage> queue;
  size_t queued_bytes = 0;
  UdpmCounters counters;  // the reassembler's copied after each datagram, and the queue's
  std::unique_ptr<UdpmReassembler> reassembler;
  std::thread thread;

  ~Impl() {
    for (const int fd : {socket_fd, wake_fd, stop_fd}) {
      if (fd >= 0) close(fd);
    }
  }

  // the reassembler's counters into ours (it runs outside the lock); with the lock held
  void CopyCounters() {
    const UdpmCounters& read = reassembler->counters();
    counters.datagrams = read.datagrams;
    counters.messages = read.messages;
    counters.malformed = read.malformed;
    counters.abandoned = read.abandoned;
  }

  bool Wanted(const std::string& channel) {
    const std::lock_guard<std::mutex> lock(mutex);
    if (capacity.count(channel) != 0) return true;
    if (!matches || matched_channels >= UdpmReceiver::kMaxMatchedChannels || !matches(channel)) {
      return false;
    }
    ++matched_channels;
    capacity[channel] = matched_capacity;
    return true;
  }

  // reads datagrams until told to stop
  void Loop() {
    sigset_t all;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, nullptr);
    std::vector<uint8_t> buffer(kDatagramBuffer);
    while (true) {
      pollfd fds[2] = {{socket_fd, POLLIN, 0}, {stop_fd, POLLIN, 0}};
      // with messages in reassembly, wake up to give up those timed out even when nothing comes
      const int timeout_ms = reassembler->partials() > 0
                                 ? std::max(1, static_cast<int>(limits.partial_timeout_s * 500))
                                 : -1;
      const int ready = poll(fds, 2, timeout_ms);
      if (ready < 0) continue;
      if (fds[1].revents != 0) return;
      if (ready == 0) {
        reassembler->Expire();
        const std::lock_guard<std::mutex> lock(mutex);
        CopyCounters();
        continue;
      }
      sockaddr_in from{};
      socklen_t from_length = sizeof(from);
      const ssize_t size = recvfrom(socket_fd, buffer.data(), buffer.size(), MSG_DONTWAIT,
                                    reinterpret_cast<sockaddr*>(&from), &from_length);
      if (size < 0) continue;
      const uint64_t sender = (uint64_t{ntohl(from.sin_addr.s_addr)} << 16) | ntohs(from.sin_port);
      UdpmMessage message;
      const bool complete =
          reassembler->Add(sender, buffer.data(), static_cast<size_t>(size), &message);
      const bool admitted = complete && (!admit || admit(message));
      const std::lock_guard<std::mutex> lock(mutex);
      CopyCounters();
      if (!complete) continue;
      if (!admitted) {
        ++counters.refused;
        continue;
      }
      const auto limit = capacity.find(message.channel);
      int& waiting = queued[message.channel];
      if (limit == capacity.end() || waiting >= limit->second ||
          queued_bytes + message.size > limits.max_queued_bytes) {
        ++counters.queue_full;
        continue;
      }
      ++waiting;
      queued_bytes += message.size;
      queue.push_back(std::move(message));
      const uint64_t one = 1;
      if (write(wake_fd, &one, sizeof(one)) < 0) {
        // the counter is full only if nobody takes: the queue's bounds hold all the same
      }
    }
  }
};

UdpmReceiver::UdpmReceiver(const UdpmAddress& address, const UdpmLimits& limits, Admit admit,
                           const std::string& program)
    : impl_(std::make_unique<Impl>()) {
  Impl& impl = *impl_;
  impl.limits = limits;
  impl.admit = std::move(admit);
  in_addr group{};
  group.s_addr = htonl(address.group);
  char group_text[INET_ADDRSTRLEN] = "?";
  inet_ntop(AF_INET, &group, group_text, sizeof(group_text));
  const std::string where = std::string(group_text) + ":" + std::to_string(address.port);
  const auto fail = [&where](const std::string& call) {
    throw std::runtime_error("cannot receive from multicast group " + where + ": " + Errno(call));
  };

  // a socket on the port, shared with every other process of the bus on this host
  impl.socket_fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (impl.socket_fd < 0) fail("socket");
  const int on = 1;
  if (setsockopt(impl.socket_fd, SOL_SOCKET, SO_REUSEADDR, &on, sizeof(on)) < 0) {
    fail("setsockopt(SO_REUSEADDR)");
  }
  if (address.recv_buf_size > 0) {
    if (setsockopt(impl.socket_fd, SOL_SOCKET, SO_RCVBUF, &address.recv_buf_size,
                   sizeof(address.recv_buf_size)) < 0) {
      fail("setsockopt(SO_RCVBUF)");
    }
    // Linux doubles what it grants (for its own bookkeeping) and caps it at net.core.rmem_max
    int granted = 0;
    socklen_t length = sizeof(granted);
    getsockopt(impl.socket_fd, SOL_SOCKET, SO_RCVBUF, &granted, &length);
    if (granted / 2 < address.recv_buf_size) {
      std::fprintf(stderr,
                   "%s: warning: the UDP receive buffer for %s is %d bytes, less than the "
                   "recv_buf_size=%d asked for (raise net.core.rmem_max); large scenes may be "
                   "lost and sent again\n",
                   program.c_str(), where.c_str(), granted / 2, address.recv_buf_size);
    }
  }
  // bound to the group, not to every address: datagrams sent to this port of another group or
  // of this host's own address (unicast) never reach the socket
  sockaddr_in bound{};
  bound.sin_family = AF_INET;
  bound.sin_addr = group;
  bound.sin_port = htons(address.port);
  if (bind(impl.socket_fd, reinterpret_cast<const sockaddr*>(&bound), sizeof(bound)) < 0) {
    fail("bind");
  }
  ip_mreq membership{};
  membership.imr_multiaddr = group;
  membership.imr_interface.s_addr = htonl(INADDR_ANY);
  if (setsockopt(impl.socket_fd, IPPROTO_IP, IP_ADD_MEMBERSHIP, &membership, sizeof(membership)) <
      0) {
    fail("setsockopt(IP_ADD_MEMBERSHIP)");
  }
  impl.wake_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  impl.stop_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (impl.wake_fd < 0 || impl.stop_fd < 0) fail("eventfd");

  Impl* shared = impl_.get();
  impl.reassembler = std::make_unique<UdpmReassembler>(
      limits, [shared](const std::string& channel) { return shared->Wanted(channel); });
  impl.thread = std::thread([shared] { shared->Loop(); });
}

UdpmReceiver::~UdpmReceiver() {
  const uint64_t one = 1;
  if (write(impl_->stop_fd, &one, sizeof(one)) == sizeof(one) && impl_->thread.joinable()) {
    impl_->thread.join();
  } else if (impl_->thread.joinable()) {
    impl_->thread.detach();
  }
}

void UdpmReceiver::Subscribe(const std::string& channel, int queue_capacity) {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  int& capacity = impl_->capacity[channel];
  capacity = std::max(capacity, queue_capacity);
}

void UdpmReceiver::SubscribeMatching(std::function<bool(const std::string&)> matches,
                                     int queue_capacity) {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->matches = std::move(matches);
  impl_->matched_capacity = queue_capacity;
}

UdpmReceiver::Taken UdpmReceiver::Take(int timeout_ms, UdpmMessage* message) {
  using Clock = std::chrono::steady_clock;
  const Clock::time_point deadline = Clock::now() + std::chrono::milliseconds(timeout_ms);
  Impl& impl = *impl_;
  while (true) {
    {
      const std::lock_guard<std::mutex> lock(impl.mutex);
      if (!impl.queue.empty()) {
        *message = std::move(impl.queue.front());
        impl.queue.pop_front();
        impl.queued_bytes -= message->size;
        --impl.queued[message->channel];
        return Taken::kMessage;
      }
      // nothing queued: the next push wakes us
      uint64_t count = 0;
      if (read(impl.wake_fd, &count, sizeof(count)) < 0) {
        // EAGAIN: nothing was pushed since the last read
      }
    }
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
    if (left <= 0) return Taken::kTimeout;
    pollfd fd = {impl.wake_fd, POLLIN, 0};
    const int ready = poll(&fd, 1, static_cast<int>(left));
    if (ready < 0 && errno == EINTR) return Taken::kInterrupted;
    if (ready == 0) return Taken::kTimeout;
  }
}

UdpmCounters UdpmReceiver::counters() const {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->counters;
}

}  // namespace stackgen
