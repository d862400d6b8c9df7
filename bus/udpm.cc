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
#include <set>
#include <stdexcept>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

#include "bus/udpm_wire.h"

namespace stackgen {
namespace {

using udpm_wire::Errno;
using udpm_wire::GetU32;
using udpm_wire::kLongHeaderBytes;
using udpm_wire::kMagicLong;
using udpm_wire::kMagicShort;
using udpm_wire::kMaxChannelBytes;
using udpm_wire::kShortHeaderBytes;
using udpm_wire::SteadySeconds;

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

// the channel at data[0, size): 1..63 bytes and a NUL within the datagram; its length, or -1
int64_t ChannelLength(const uint8_t* data, size_t size) {
  const size_t limit = std::min(size, kMaxChannelBytes + 1);
  const void* nul = std::memchr(data, '\0', limit);
  if (nul == nullptr) return -1;
  const size_t length = static_cast<size_t>(static_cast<const uint8_t*>(nul) - data);
  return length == 0 ? -1 : static_cast<int64_t>(length);
}

uint16_t GetU16(const uint8_t* in) { return static_cast<uint16_t>((in[0] << 8) | in[1]); }

// tables of messages keyed by (sender, msg_seqno): the entries of `sender`
template <typename Table>
int EntriesOf(const Table& table, uint64_t sender) {
  int count = 0;
  for (auto it = table.lower_bound({sender, 0}); it != table.end() && it->first.first == sender;
       ++it) {
    ++count;
  }
  return count;
}

// the entry with the smallest `age` among those `eligible` takes (by key); end() if none
template <typename Table, typename Age, typename Eligible>
typename Table::iterator Oldest(Table& table, Age age, Eligible eligible) {
  auto oldest = table.end();
  for (auto it = table.begin(); it != table.end(); ++it) {
    if (!eligible(it->first)) continue;
    if (oldest == table.end() || age(it->second) < age(oldest->second)) oldest = it;
  }
  return oldest;
}

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
  const auto number = [&url](const std::string& option, const std::string& name, long low,
                             long high, const std::string& unit) {
    const std::string text = option.substr(name.size() + 1);
    char* end = nullptr;
    const long value = std::strtol(text.c_str(), &end, 10);
    if (text.empty() || *end != '\0' || value < low || value > high) {
      throw std::runtime_error("bad " + name + " in LCM URL " + url + " (" + unit +
                               std::to_string(low) + ".." + std::to_string(high) + ")");
    }
    return static_cast<int>(value);
  };
  for (size_t at = query; at != std::string::npos && at + 1 < url.size();) {
    const size_t next = url.find('&', at + 1);
    const std::string option = url.substr(at + 1, next == std::string::npos ? next : next - at - 1);
    at = next;
    if (option.rfind("recv_buf_size=", 0) == 0) {
      address.recv_buf_size = number(option, "recv_buf_size", 0, 1L << 30, "bytes, ");
    } else if (option.rfind("ttl=", 0) == 0) {
      address.ttl = number(option, "ttl", 0, 255, "");
    } else if (option.rfind("mtu=", 0) == 0) {
      address.mtu = number(option, "mtu", 576, 65535, "bytes, ");
    } else {
      // a typo (tll=1) would otherwise leave a default in force without a word
      throw std::runtime_error("unknown option '" + option + "' in LCM URL " + url +
                               " (udpm:// takes ttl=, recv_buf_size= and mtu=)");
    }
  }
  return address;
}

std::string ReceiveSummary(const UdpmCounters& counters) {
  return "received " + std::to_string(counters.datagrams) +
         " datagrams: " + std::to_string(counters.malformed) + " malformed, " +
         std::to_string(counters.abandoned) + " messages given up incomplete, " +
         std::to_string(counters.queue_full) + " dropped for a full queue, " +
         std::to_string(counters.repaired) + " completed by asking for " +
         std::to_string(counters.repair_asks) +
         " repairs";
}

// ---------------------------------------------------------------------------------------------
// UdpmReassembler

struct UdpmReassembler::Impl {
  // one message in reassembly: the fragments heard, each kept as it came (nothing is allocated
  // for bytes that did not arrive; the message is put together when its last fragment comes)
  struct Partial {
    std::string channel;
    uint32_t size = 0;
    uint16_t fragments = 0;
    std::vector<bool> heard;  // by fragment number
    std::map<uint32_t, std::vector<uint8_t>> pieces;  // by offset
    uint64_t bytes_heard = 0;
    size_t cost = 0;  // what it holds, bookkeeping included (kPartialBytes, kFragmentBytes)
    uint64_t last_use = 0;
    double last_heard_s = 0;
    double last_asked_s = 0;  // a repair ask (0: none yet)
    int asks = 0;             // asks since a fragment last came
    bool asked = false;       // asked at least once
  };
  // a message: its sender and msg_seqno
  using Key = std::pair<uint64_t, uint32_t>;

  UdpmLimits limits;
  std::function<bool(const std::string&)> wanted;
  Repair repair;
  std::map<Key, Partial> partials;
  size_t partial_bytes = 0;
  uint64_t uses = 0;
  UdpmCounters counters;
  // the messages completed lately (or of channels not wanted), so that a late copy of a fragment
  // begins nothing
  std::deque<Key> completed;
  std::set<Key> completed_set;
  static constexpr size_t kCompletedKept = 256;
  // messages heard without their fragment 0 (lost on the way): nothing is kept of them but that
  // they exist, and they ask for their fragment 0, whose channel says whether they are wanted
  struct Orphan {
    uint32_t size = 0;
    uint16_t fragments = 0;
    double first_heard_s = 0;
    double last_asked_s = 0;
    int asks = 0;
  };
  std::map<Key, Orphan> orphans;

  void Done(const Key& key) {
    if (!completed_set.insert(key).second) return;
    completed.push_back(key);
    if (completed.size() > kCompletedKept) {
      completed_set.erase(completed.front());
      completed.pop_front();
    }
  }

  // notes a message heard without its fragment 0 (when repairs are asked for at all)
  void NoteOrphan(const Key& key, uint32_t size, uint16_t fragments, double now_s) {
    if (!repair || orphans.count(key) != 0) return;
    // at most max_partials of them, and max_partials_per_sender of one sender: the oldest goes
    const auto age = [](const Orphan& orphan) { return orphan.first_heard_s; };
    if (EntriesOf(orphans, key.first) >= limits.max_partials_per_sender) {
      orphans.erase(Oldest(orphans, age, [&](const Key& other) { return other.first == key.first; }));
    }
    if (static_cast<int>(orphans.size()) >= limits.max_partials) {
      orphans.erase(Oldest(orphans, age, [](const Key&) { return true; }));
    }
    orphans[key] = Orphan{size, fragments, now_s, 0, 0};
  }

  void Forget(std::map<Key, Partial>::iterator it) {
    partial_bytes -= it->second.cost;
    partials.erase(it);
  }

  // a datagram that breaks the rules; the message it names in reassembly goes with it
  bool Malformed(const Key* key = nullptr) {
    ++counters.malformed;
    if (key != nullptr) {
      const auto found = partials.find(*key);
      if (found != partials.end()) Forget(found);
    }
    return false;
  }

  // room for `bytes` more (and, with `another`, one more message of `keep`'s sender) in
  // reassembly, the least recent other than `keep` giving way
  void MakeRoom(size_t bytes, bool another, const Key& keep) {
    const auto age = [](const Partial& partial) { return partial.last_use; };
    const auto give_way = [&](auto&& eligible) {
      const auto oldest = Oldest(partials, age, [&](const Key& key) {
        return key != keep && eligible(key);
      });
      if (oldest == partials.end()) return false;
      ++counters.abandoned;
      Forget(oldest);
      return true;
    };
    // the sender's own limit first: its least recent message gives way
    const auto of_sender = [&](const Key& key) { return key.first == keep.first; };
    if (another) {
      int others = EntriesOf(partials, keep.first) - (partials.count(keep) != 0 ? 1 : 0);
      while (others >= limits.max_partials_per_sender && give_way(of_sender)) --others;
    }
    while (partial_bytes + bytes > limits.max_partial_bytes ||
           (another && static_cast<int>(partials.size()) >= limits.max_partials)) {
      if (!give_way([](const Key&) { return true; })) return;
    }
  }

  // the ask for what `partial` lacks, from its first missing fragment
  void Ask(const Key& key, Partial& partial, double now_s) {
    UdpmRepair ask;
    ask.sender = key.first;
    ask.seqno = key.second;
    ask.size = partial.size;
    ask.fragments = partial.fragments;
    uint32_t first = 0;
    while (first < partial.fragments && partial.heard[first]) ++first;
    if (first >= partial.fragments) return;
    ask.first = first;
    const uint32_t bits = std::min<uint32_t>(kMaxRepairBits, partial.fragments - first);
    ask.missing.assign((bits + 7) / 8, 0);
    for (uint32_t i = 0; i < bits; ++i) {
      if (!partial.heard[first + i]) ask.missing[i / 8] |= static_cast<uint8_t>(1u << (i % 8));
    }
    partial.last_asked_s = now_s;
    partial.asked = true;
    ++partial.asks;
    if (repair(ask)) ++counters.repair_asks;
  }

  // messages that heard no fragment for partial_timeout_s are given up; those quiet for
  // repair_after_s ask for what they lack (Add looks every repair_after_s, or quarter timeout)
  double swept_s = 0;
  void Expire(double now_s) {
    swept_s = now_s;
    for (auto it = orphans.begin(); it != orphans.end();) {
      Orphan& orphan = it->second;
      if (now_s - orphan.first_heard_s >= limits.partial_timeout_s ||
          orphan.asks >= limits.max_repair_asks) {
        it = orphans.erase(it);
        continue;
      }
      if (now_s - std::max(orphan.first_heard_s, orphan.last_asked_s) >= limits.repair_after_s) {
        UdpmRepair ask;
        ask.sender = it->first.first;
        ask.seqno = it->first.second;
        ask.size = orphan.size;
        ask.fragments = orphan.fragments;
        ask.first = 0;
        ask.missing = {1};
        orphan.last_asked_s = now_s;
        ++orphan.asks;
        if (repair(ask)) ++counters.repair_asks;
      }
      ++it;
    }
    for (auto it = partials.begin(); it != partials.end();) {
      Partial& partial = it->second;
      if (now_s - partial.last_heard_s >= limits.partial_timeout_s) {
        ++counters.abandoned;
        partial_bytes -= partial.cost;
        it = partials.erase(it);
        continue;
      }
      if (repair && partial.asks < limits.max_repair_asks &&
          now_s - std::max(partial.last_heard_s, partial.last_asked_s) >= limits.repair_after_s) {
        Ask(it->first, partial, now_s);
      }
      ++it;
    }
  }

  double Interval() const {
    return repair ? std::min(limits.repair_after_s, limits.partial_timeout_s / 4)
                  : limits.partial_timeout_s / 4;
  }

  bool Short(uint64_t sender, const uint8_t* data, size_t size, UdpmMessage* message) {
    const int64_t length = ChannelLength(data + kShortHeaderBytes, size - kShortHeaderBytes);
    if (length < 0) return Malformed();
    std::string channel(reinterpret_cast<const char*>(data + kShortHeaderBytes),
                        static_cast<size_t>(length));
    if (!wanted(channel)) return false;
    const size_t start = kShortHeaderBytes + static_cast<size_t>(length) + 1;
    message->channel = std::move(channel);
    message->sender = sender;
    message->size = size - start;
    message->data.reset(new uint8_t[std::max<size_t>(1, message->size)]);
    std::memcpy(message->data.get(), data + start, message->size);
    ++counters.messages;
    return true;
  }

  bool Fragment(uint64_t sender, const uint8_t* data, size_t size, double now_s,
                UdpmMessage* message) {
    if (size < kLongHeaderBytes) return Malformed();
    const uint32_t seqno = GetU32(data + 4);
    const uint32_t msg_size = GetU32(data + 8);
    const uint32_t offset = GetU32(data + 12);
    const uint16_t number = GetU16(data + 16);
    const uint16_t fragments = GetU16(data + 18);
    const Key key{sender, seqno};
    if (msg_size == 0 || msg_size > limits.max_message_bytes || fragments == 0 ||
        number >= fragments) {
      return Malformed(&key);
    }
    auto found = partials.find(key);
    if (found == partials.end() && completed_set.count(key) != 0) {
      ++counters.repeats;  // a late copy of a message already complete (or not wanted)
      return false;
    }
    if (found != partials.end() &&
        (found->second.size != msg_size || found->second.fragments != fragments)) {
      return Malformed(&key);
    }

    // fragment 0 begins a message: its channel first
    const uint8_t* bytes = data + kLongHeaderBytes;
    size_t length = size - kLongHeaderBytes;
    if (number == 0) {
      const int64_t channel_length = ChannelLength(bytes, length);
      if (channel_length < 0 || offset != 0) return Malformed(&key);
      std::string channel(reinterpret_cast<const char*>(bytes),
                          static_cast<size_t>(channel_length));
      bytes += channel_length + 1;
      length -= static_cast<size_t>(channel_length) + 1;
      if (found != partials.end()) {
        if (found->second.channel != channel) return Malformed(&key);
      } else {
        const bool was_orphan = orphans.erase(key) > 0;
        if (!wanted(channel)) {
          Done(key);
          return false;
        }
        // what the whole message would hold: more than reassembly may, and it is never begun
        if (MessageCost(msg_size, fragments) > limits.max_partial_bytes) return Malformed();
        const size_t cost = kPartialBytes + fragments / 8;
        MakeRoom(cost, true, key);
        Partial partial;
        partial.channel = std::move(channel);
        partial.size = msg_size;
        partial.fragments = fragments;
        partial.heard.assign(fragments, false);
        partial.cost = cost;
        partial.asked = was_orphan;
        found = partials.emplace(key, std::move(partial)).first;
        partial_bytes += cost;
      }
    } else if (found == partials.end()) {
      // its fragment 0 was not heard: nothing to add it to, but it can be asked for
      NoteOrphan(key, msg_size, fragments, now_s);
      return false;
    }

    // the fragment's place: inside the message, over no other; the same place again is a repeat
    Partial& partial = found->second;
    const uint64_t end = uint64_t{offset} + length;
    if (length == 0 || end > partial.size) return Malformed(&key);
    const auto after = partial.pieces.lower_bound(offset);
    if (partial.heard[number]) {
      if (after != partial.pieces.end() && after->first == offset &&
          after->second.size() == length) {
        ++counters.repeats;
        return false;
      }
      return Malformed(&key);
    }
    if (after != partial.pieces.end() && after->first < end) return Malformed(&key);
    if (after != partial.pieces.begin() &&
        std::prev(after)->first + std::prev(after)->second.size() > offset) {
      return Malformed(&key);
    }
    const size_t cost = length + kFragmentBytes;
    MakeRoom(cost, false, key);
    partial.pieces.emplace_hint(after, offset, std::vector<uint8_t>(bytes, bytes + length));
    partial.heard[number] = true;
    partial.bytes_heard += length;
    partial.cost += cost;
    partial_bytes += cost;
    partial.last_use = ++uses;
    partial.last_heard_s = now_s;
    partial.asks = 0;
    if (partial.pieces.size() < partial.fragments) return false;

    // every fragment heard: complete when they cover the message
    if (partial.bytes_heard != partial.size) return Malformed(&key);
    message->channel = std::move(partial.channel);
    message->sender = sender;
    message->data.reset(new uint8_t[partial.size]);
    for (const auto& [at, piece] : partial.pieces) {
      std::memcpy(message->data.get() + at, piece.data(), piece.size());
    }
    message->size = partial.size;
    if (partial.asked) ++counters.repaired;
    Forget(found);
    Done(key);
    ++counters.messages;
    return true;
  }
};

UdpmReassembler::UdpmReassembler(const UdpmLimits& limits,
                                 std::function<bool(const std::string&)> wanted, Repair repair)
    : impl_(std::make_unique<Impl>()) {
  impl_->limits = limits;
  impl_->wanted = std::move(wanted);
  impl_->repair = std::move(repair);
}

UdpmReassembler::~UdpmReassembler() = default;

bool UdpmReassembler::Add(uint64_t sender, const uint8_t* data, size_t size, UdpmMessage* message) {
  return Add(sender, data, size, SteadySeconds(), message);
}

bool UdpmReassembler::Add(uint64_t sender, const uint8_t* data, size_t size, double now_s,
                          UdpmMessage* message) {
  Impl& impl = *impl_;
  ++impl.counters.datagrams;
  if (now_s - impl.swept_s >= impl.Interval()) impl.Expire(now_s);
  if (size < kShortHeaderBytes || size >= kDatagramBuffer) return impl.Malformed();
  const uint32_t magic = GetU32(data);
  if (magic == kMagicShort) return impl.Short(sender, data, size, message);
  if (magic == kMagicLong) return impl.Fragment(sender, data, size, now_s, message);
  return impl.Malformed();
}

void UdpmReassembler::Expire() { Expire(SteadySeconds()); }

void UdpmReassembler::Expire(double now_s) { impl_->Expire(now_s); }

double UdpmReassembler::NextDue(double now_s) const {
  const Impl& impl = *impl_;
  double due = -1;
  for (const auto& [key, orphan] : impl.orphans) {
    const double at =
        std::max(orphan.first_heard_s, orphan.last_asked_s) + impl.limits.repair_after_s;
    const double left = std::max(0.0, at - now_s);
    if (due < 0 || left < due) due = left;
  }
  for (const auto& [key, partial] : impl.partials) {
    double at = partial.last_heard_s + impl.limits.partial_timeout_s;
    if (impl.repair && partial.asks < impl.limits.max_repair_asks) {
      at = std::min(at, std::max(partial.last_heard_s, partial.last_asked_s) +
                            impl.limits.repair_after_s);
    }
    const double left = std::max(0.0, at - now_s);
    if (due < 0 || left < due) due = left;
  }
  return due;
}

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
    counters.repeats = read.repeats;
    counters.repair_asks = read.repair_asks;
    counters.repaired = read.repaired;
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
      // with messages in reassembly, wake up to ask for what they lack and to give up those timed
      // out even when nothing comes
      const double due_s = reassembler->NextDue(SteadySeconds());
      const int timeout_ms = due_s < 0 ? -1 : std::max(1, static_cast<int>(due_s * 1000) + 1);
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
                           const std::string& program, UdpmReassembler::Repair repair)
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
      limits, [shared](const std::string& channel) { return shared->Wanted(channel); },
      std::move(repair));
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
