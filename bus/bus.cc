#include "bus/bus.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <exception>
#include <list>
#include <map>
#include <mutex>
#include <optional>
#include <set>

#include <openssl/rand.h>
#include <lcm/lcm-cpp.hpp>
#include <stackgen/fragment_repair.hpp>
#include <stackgen/liveness.hpp>

#include "bus/channels.h"
#include "bus/liveness.h"
#include "bus/udpm.h"
#include "contract/splitmix.h"

namespace stackgen {
namespace {

// throws a one-line error when a udpm:// URL's multicast group cannot be reached from here.
void CheckMulticastRoute(const std::string& url) {
  if (url.rfind("udpm://", 0) != 0) return;
  const UdpmAddress address = ParseUdpmUrl(url);
  sockaddr_in group{};
  group.sin_family = AF_INET;
  group.sin_port = htons(address.port);
  group.sin_addr.s_addr = htonl(address.group);
  char group_text[INET_ADDRSTRLEN] = "?";
  inet_ntop(AF_INET, &group.sin_addr, group_text, sizeof(group_text));

  // connecting a UDP socket only looks up the route: it fails when multicast has none.
  const int fd = socket(AF_INET, SOCK_DGRAM, 0);
  if (fd < 0) throw std::runtime_error(std::string("cannot open a UDP socket: ") + strerror(errno));
  const int result = connect(fd, reinterpret_cast<const sockaddr*>(&group), sizeof(group));
  const int error = errno;
  close(fd);
  if (result != 0) {
    throw std::runtime_error(std::string("multicast to ") + group_text + " is not possible here (" +
                             strerror(error) +
                             "); enable it with `sudo ip route add 224.0.0.0/4 dev lo` "
                             "(this host only) or pass another --lcm-url");
  }
}

}  // namespace

std::string ResolveLcmUrl(const std::string& flag_value) {
  if (!flag_value.empty()) return flag_value;
  const char* from_env = std::getenv("STACKGEN_LCM_URL");
  if (from_env != nullptr && from_env[0] != '\0') return from_env;
  return kDefaultLcmUrl;
}

// one handler of a channel; a Subscription that ends when dropped clears `handler` (a shared
// pointer: a handler that ends its own subscription while it runs is kept alive by the call)
struct Subscription::Slot {
  std::shared_ptr<std::function<void(const uint8_t* data, size_t size)>> handler;
};

void Subscription::Reset() {
  if (!end_when_dropped_) {
    slot_.reset();
    return;
  }
  end_when_dropped_ = false;
  if (const std::shared_ptr<Slot> slot = slot_.lock()) slot->handler.reset();
  slot_.reset();
}

bool Subscription::active() const {
  const std::shared_ptr<Slot> slot = slot_.lock();
  return slot && slot->handler;
}

struct Bus::Impl {
  // what LCM's callback gets as its context: one per channel, so that a message is checked once
  // (its counter would look replayed to a second check) and then handed to each handler.
  struct Subscriber {
    Impl* impl;
    std::string channel;
    // the handlers, in the order subscribed; one whose Subscription ended has none (and is
    // forgotten when the next message comes)
    std::vector<std::shared_ptr<Subscription::Slot>> handlers;
    lcm::Subscription* subscription = nullptr;
    int queue_capacity = 0;
  };

  // what the messages heard on one channel showed of their senders' keys (KeyMismatch)
  struct KeyUse {
    KeyEvidence evidence;
    Clock::TimePoint first_mismatch;
  };

  std::string url;
  BusOptions options;
  // signs what is published, checks what is received (auth.h); a buffer for sealed bytes
  std::unique_ptr<MessageAuth> auth;
  std::vector<uint8_t> sealed;
  // the fault-injection engine and what it dropped
  // one engine per channel, each seeded from (fault_seed, channel): the drops on one channel
  // do not shift with how many messages another carried (status and config are timed)
  std::map<std::string, SplitMix64> fault_engines;
  int64_t fault_dropped = 0;
  // a file:// log was read to its end
  bool log_ended = false;
  // an exception a handler threw, kept until HandleFor can rethrow it outside LCM's C code.
  std::exception_ptr pending_error;
  // the first refusal of each kind (unsigned, forged, replayed) was reported; a message of another
  // process was taken
  std::atomic<bool> reported[4] = {false, false, false, false};
  std::atomic<bool> taken_any{false};
  // by channel; written by the receiving thread too
  mutable std::mutex key_use_mutex;
  std::map<std::string, KeyUse> key_use;
  // subscribers live here (a list: addresses stay valid) and outlive the LCM instance and the
  // receiver below.
  std::list<Subscriber> subscribers;
  // LCM sends and receives memq:// and file://; udpm:// is sent and received by our own code
  // (udpm.h: liblcm's receiver can be crashed by two datagrams, and its sender cannot keep
  // datagrams within the MTU or send a lost fragment again), so LCM is not opened there
  std::unique_ptr<lcm::LCM> lcm;
  std::unique_ptr<UdpmSender> sender;
  // the addresses and ports that sent a message this bus verified (or, open, any message), on
  // the receiver's thread: only they are asked for missing fragments, so a stranger's fragments
  // cannot make this process send asks (kMaxPeerAddresses at most, the oldest giving way)
  std::set<uint64_t> peer_addresses;
  std::deque<uint64_t> peer_order;
  static constexpr size_t kMaxPeerAddresses = 4096;

  void NotePeer(uint64_t address) {
    if (!peer_addresses.insert(address).second) return;
    peer_order.push_back(address);
    if (peer_order.size() > kMaxPeerAddresses) {
      peer_addresses.erase(peer_order.front());
      peer_order.pop_front();
    }
  }
  // the liveness check of a keyed udpm:// bus, run by the receiver's thread (declared before
  // the receiver, so that it outlives the thread)
  std::unique_ptr<LivenessCheck> liveness;
  std::unique_ptr<UdpmReceiver> receiver;

  // true with probability `fraction`, from the channel's seeded engine
  bool Drop(double fraction, const std::string& channel) {
    if (fraction <= 0) return false;
    auto engine = fault_engines.find(channel);
    if (engine == fault_engines.end()) {
      uint64_t seed = options.fault_seed;
      for (const char c : channel) seed = SplitMixHash(seed ^ static_cast<uint8_t>(c));
      engine = fault_engines.emplace(channel, SplitMix64(seed)).first;
    }
    const uint64_t z = engine->second.Next();
    const bool drop = static_cast<double>(z >> 11) * 0x1.0p-53 < fraction;
    if (drop) ++fault_dropped;
    return drop;
  }

  // says on stderr why a message was refused when it is the first of its kind, once this bus
  // has taken a message: before that, refusals may all be a key that differs from the peers',
  // which the programs report in one line (KeyMismatch) rather than as warnings
  void ReportRefusal(const AuthCounters& before, const std::string& why) {
    if (!taken_any) return;
    const AuthCounters now = auth->counters();
    const bool first[4] = {before.unsigned_messages < now.unsigned_messages,
                           before.forged < now.forged, before.replayed < now.replayed,
                           before.relayed < now.relayed};
    for (int kind = 0; kind < 4; ++kind) {
      if (first[kind] && !reported[kind].exchange(true)) {
        std::fprintf(stderr, "%s: warning: %s; further ones are only counted (status: refused)\n",
                     program_invocation_short_name, why.c_str());
        return;
      }
    }
  }

  // the time on the bus's clock (BusOptions::clock)
  Clock::TimePoint Now() const {
    return (options.clock != nullptr ? *options.clock : SteadyClock()).Now();
  }

  // notes what a message heard on `channel` showed of its sender's key
  void NoteKeyUse(const std::string& channel, const uint8_t* data, size_t size, bool verified) {
    const std::lock_guard<std::mutex> lock(key_use_mutex);
    KeyUse& use = key_use[channel];
    const int64_t mismatched = use.evidence.mismatched;
    use.evidence.Note(*auth, data, size, verified);
    if (mismatched == 0 && use.evidence.mismatched > 0) {
      use.first_mismatch = Now();
    }
  }

  // hands a received message to the handlers of its channel once it passed the key check (its
  // first half, Verify, already done on the receiving thread when `verified`)
  void Deliver(Subscriber* subscriber, const uint8_t* data, size_t data_size, bool verified) {
    if (pending_error) return;
    if (Drop(options.drop_receive_fraction, subscriber->channel)) return;
    try {
      // the key check; refused messages go no further
      std::string why;
      const AuthCounters before = auth->counters();
      const std::string& channel = subscriber->channel;
      if (!verified) {
        const bool passed = auth->Verify(channel, data, data_size, &why) >= 0;
        NoteKeyUse(channel, data, data_size, passed);
        if (!passed) {
          ReportRefusal(before, why);
          return;
        }
      }
      const int64_t size = auth->Admit(channel, data, data_size, &why);
      if (size < 0) {
        ReportRefusal(before, why);
        return;
      }
      // a message of another process: refusals are no longer a key that differs from all peers'
      Trailer trailer;
      if (!ReadTrailer(data, data_size, &trailer) || trailer.sender != auth->sender()) {
        taken_any = true;
      }
      auto& slots = subscriber->handlers;
      slots.erase(std::remove_if(slots.begin(), slots.end(),
                                 [](const auto& slot) { return !slot->handler; }),
                  slots.end());
      // by index, over the handlers there now: a handler may end its own or another's
      // subscription (its slot stays until the next message), or subscribe anew (appended)
      for (size_t i = 0, count = slots.size(); i < count; ++i) {
        const auto handler = slots[i]->handler;  // alive through the call, whatever it ends
        if (handler) (*handler)(data, static_cast<size_t>(size));
      }
    } catch (...) {
      pending_error = std::current_exception();
    }
  }

  // LCM's callback (memq://, file://)
  static void Dispatch(const lcm::ReceiveBuffer* buffer, const std::string&,
                       Subscriber* subscriber) {
    subscriber->impl->Deliver(subscriber, static_cast<const uint8_t*>(buffer->data),
                              buffer->data_size, false);
  }

  // on the receiver's thread, before a message is queued: the first half of the key check (a
  // message not signed with the key is dropped), the liveness check's own messages, and the
  // messages of senders that have not answered it (dropped: they are challenged)
  bool Screen(const UdpmMessage& message) {
    const uint8_t* data = message.data.get();
    if (!auth->keyed()) {
      NotePeer(message.sender);
      if (message.channel == kRepairChannel) {
        Repair(data, message.size);
        return false;
      }
      NoteKeyUse(message.channel, data, message.size, true);
      return true;
    }
    std::string why;
    const AuthCounters before = auth->counters();
    const bool verified = auth->Verify(message.channel, data, message.size, &why) >= 0;
    NoteKeyUse(message.channel, data, message.size, verified);
    if (!verified) {
      ReportRefusal(before, why);
      return false;
    }
    NotePeer(message.sender);
    Trailer trailer;
    ReadTrailer(data, message.size, &trailer);
    if (message.channel == kLivenessChannel) {
      stackgen::liveness check;
      if (DecodeBounded(data, message.size - kAuthTrailerBytes, options.decode_limits, &check,
                        nullptr)) {
        liveness->Handle(check, trailer.sender, trailer.counter, UnixMicros());
      }
      return false;
    }
    if (!auth->Live(trailer.sender)) {
      liveness->Unanswered(trailer.sender, message.channel, UnixMicros());
      return false;
    }
    if (message.channel == kRepairChannel) {
      if (auth->Admit(message.channel, data, message.size, nullptr) >= 0) {
        Repair(data, message.size - kAuthTrailerBytes);
      }
      return false;
    }
    return true;
  }

  // a receiver asks for fragments (on the receiver's thread): this bus's sender sends those of
  // its own messages again
  void Repair(const uint8_t* data, size_t size) {
    fragment_repair ask;
    if (!DecodeBounded(data, size, options.decode_limits, &ask, nullptr)) return;
    if (ask.seqno < 0 || ask.seqno > UINT32_MAX || ask.size <= 0 || ask.fragments <= 0 ||
        ask.fragments > 65535 || ask.first < 0 || ask.missing_bytes < 0 ||
        static_cast<size_t>(ask.missing_bytes) * 8 > kMaxRepairBits) {
      return;
    }
    UdpmRepair repair;
    repair.sender = static_cast<uint64_t>(ask.sender);
    repair.seqno = static_cast<uint32_t>(ask.seqno);
    repair.size = static_cast<uint32_t>(ask.size);
    repair.fragments = static_cast<uint16_t>(ask.fragments);
    repair.first = static_cast<uint32_t>(ask.first);
    repair.missing.assign(ask.missing, ask.missing + ask.missing_bytes);
    try {
      sender->Repair(repair);
    } catch (const std::exception&) {
      // sending failed: the receiver asks again, or its delivery layer asks for the message
    }
  }

  // asks a message's sender for the fragments this bus lacks (on the receiver's thread), when it
  // is a peer
  bool AskRepair(const UdpmRepair& repair) {
    if (peer_addresses.count(repair.sender) == 0) return false;
    fragment_repair ask{};
    ask.header.seq = -1;
    ask.header.generator_id = -1;
    ask.header.utime = UnixMicros();
    ask.sender = static_cast<int64_t>(repair.sender);
    ask.seqno = repair.seqno;
    ask.size = static_cast<int32_t>(repair.size);
    ask.fragments = repair.fragments;
    ask.first = static_cast<int32_t>(repair.first);
    ask.missing_bytes = static_cast<int16_t>(std::min<size_t>(repair.missing.size(), 1024));
    std::copy_n(repair.missing.begin(), ask.missing_bytes, ask.missing);
    const std::vector<uint8_t> bytes = EncodeMessage(ask);
    std::vector<uint8_t> sealed_bytes;
    auth->Seal(kRepairChannel, bytes.data(), bytes.size(), &sealed_bytes);
    try {
      sender->Send(kRepairChannel, sealed_bytes.data(), sealed_bytes.size());
    } catch (const std::exception&) {
      return false;  // asked again later, while the message waits
    }
    return true;
  }

  // publishes a liveness message from the receiver's thread (the sender takes a lock)
  void SendLiveness(const stackgen::liveness& message) {
    const std::vector<uint8_t> bytes = EncodeMessage(message);
    std::vector<uint8_t> sealed_bytes;
    auth->Seal(kLivenessChannel, bytes.data(), bytes.size(), &sealed_bytes);
    sender->Send(kLivenessChannel, sealed_bytes.data(), sealed_bytes.size());
  }

  Subscriber* Find(const std::string& channel) {
    for (Subscriber& subscriber : subscribers) {
      if (subscriber.channel == channel) return &subscriber;
    }
    return nullptr;
  }
};

namespace {

// LCM at `url`. LCM says why it cannot open a URL on stderr ("Error: LCM provider "x" not
// found"): that text goes into the one error line instead (anything else it prints is passed on).
std::unique_ptr<lcm::LCM> OpenLcm(const std::string& url) {
  std::unique_ptr<lcm::LCM> opened;
  std::string said;
  {
    std::fflush(stderr);
    std::FILE* capture = std::tmpfile();
    const int saved = capture != nullptr ? dup(STDERR_FILENO) : -1;
    const bool capturing = saved >= 0 && dup2(fileno(capture), STDERR_FILENO) >= 0;
    opened = std::make_unique<lcm::LCM>(url);
    if (capturing) {
      std::fflush(stderr);
      dup2(saved, STDERR_FILENO);
      std::rewind(capture);
      char buffer[512];
      for (size_t n; (n = std::fread(buffer, 1, sizeof(buffer), capture)) > 0;) {
        said.append(buffer, n);
      }
    }
    if (saved >= 0) close(saved);
    if (capture != nullptr) std::fclose(capture);
  }
  if (!opened->good()) {
    // "Error: Failed to open /x.log: No such file or directory\n" -> "Failed to open ..."
    std::string why = said;
    while (!why.empty() && (why.back() == '\n' || why.back() == ' ')) why.pop_back();
    for (size_t line; (line = why.find('\n')) != std::string::npos;) why[line] = ';';
    if (why.rfind("Error: ", 0) == 0) why.erase(0, 7);
    throw std::runtime_error("cannot open the LCM bus at " + url + (why.empty() ? "" : ": " + why));
  }
  if (!said.empty()) std::fputs(said.c_str(), stderr);
  return opened;
}

}  // namespace

Bus::Bus(const std::string& url, const BusOptions& options) : impl_(std::make_unique<Impl>()) {
  for (const double fraction : {options.drop_receive_fraction, options.drop_publish_fraction}) {
    if (!(fraction >= 0.0 && fraction < 1.0)) {
      throw std::invalid_argument("a bus drop fraction must be in [0, 1), got " +
                                  std::to_string(fraction));
    }
  }
  impl_->url = url;
  impl_->options = options;
  CheckMulticastRoute(url);
  // the key before the bus: a key file that cannot be used is one line, and nothing is opened
  const bool is_log = url.rfind("file://", 0) == 0;
  const bool is_udpm = url.rfind("udpm://", 0) == 0;
  impl_->auth = std::make_unique<MessageAuth>(
      options.open_bus ? "" : ResolveBusKeyFile(options.key_file), !is_log && !options.replay,
      BusTag(url));
  if (options.open_bus && is_udpm) {
    static std::atomic<bool> warned{false};
    if (!warned.exchange(true)) {
      std::fprintf(stderr,
                   "%s: warning: an open bus (--open-bus): no bus key, every process that can "
                   "send to %s is trusted\n",
                   program_invocation_short_name, url.c_str());
    }
  }
  if (!is_udpm) impl_->lcm = OpenLcm(url);
  if (is_udpm) {
    Impl* impl = impl_.get();
    const UdpmAddress address = ParseUdpmUrl(url);
    impl_->sender = std::make_unique<UdpmSender>(address);
    if (impl_->auth->keyed()) {
      impl_->liveness = std::make_unique<LivenessCheck>(
          impl_->auth.get(), [impl](const liveness& message) { impl->SendLiveness(message); },
          [](const std::string& line) {
            std::fprintf(stderr, "%s: warning: %s\n", program_invocation_short_name, line.c_str());
          },
          [] {
            int64_t nonce = 0;
            if (RAND_bytes(reinterpret_cast<unsigned char*>(&nonce), sizeof(nonce)) != 1) {
              throw std::runtime_error("OpenSSL cannot draw a random nonce");
            }
            return nonce;
          });
    }
    UdpmLimits limits;
    limits.max_message_bytes = options.decode_limits.max_message_bytes + kAuthTrailerBytes;
    impl_->receiver = std::make_unique<UdpmReceiver>(
        address, limits, [impl](const UdpmMessage& message) { return impl->Screen(message); },
        program_invocation_short_name,
        [impl](const UdpmRepair& repair) { return impl->AskRepair(repair); });
    impl_->receiver->Subscribe(kRepairChannel, 1);
    if (impl_->liveness) {
      impl_->receiver->Subscribe(kLivenessChannel, 1);
      // every process hears that this one starts, and answers
      if (impl_->auth->liveness()) impl_->liveness->Start(UnixMicros());
    }
  }
}

Bus::~Bus() = default;

const std::string& Bus::url() const { return impl_->url; }

int64_t BusState::fault_dropped() const { return bus_.impl_->fault_dropped; }

bool BusState::log_ended() const { return bus_.impl_->log_ended; }

bool BusState::keyed() const { return bus_.impl_->auth->keyed(); }

const std::string& BusState::key_file() const { return bus_.impl_->auth->key_file(); }

uint64_t BusState::key_id() const { return bus_.impl_->auth->key_id(); }

std::string BusState::KeyMismatch(const std::vector<std::string>& channels, double seconds) const {
  // what was heard on those channels together, since the first mismatch among them
  KeyEvidence all;
  std::optional<Clock::TimePoint> first;
  std::string names;
  {
    const std::lock_guard<std::mutex> lock(bus_.impl_->key_use_mutex);
    for (const std::string& channel : channels) {
      names += (names.empty() ? "" : ", ") + channel;
      const auto found = bus_.impl_->key_use.find(channel);
      if (found == bus_.impl_->key_use.end()) continue;
      all.Add(found->second.evidence);
      if (found->second.evidence.mismatched > 0 &&
          (!first || found->second.first_mismatch < *first)) {
        first = found->second.first_mismatch;
      }
    }
  }
  if (!first || std::chrono::duration<double>(bus_.impl_->Now() - *first).count() < seconds) {
    return "";
  }
  return all.Mismatch(*bus_.impl_->auth, "the messages on " + names + " of " + bus_.impl_->url);
}

void BusState::WatchKeys(const std::vector<std::string>& channels) {
  for (const std::string& channel : channels) {
    if (bus_.impl_->Find(channel) == nullptr) {
      bus_.SubscribeBytes(
          channel, [](const uint8_t*, size_t) {}, 1);
    }
  }
}

int BusState::handlers(const std::string& channel) const {
  const Bus::Impl::Subscriber* subscriber = bus_.impl_->Find(channel);
  if (subscriber == nullptr) return 0;
  return static_cast<int>(std::count_if(subscriber->handlers.begin(), subscriber->handlers.end(),
                                        [](const auto& slot) { return slot->handler != nullptr; }));
}

UdpmCounters BusState::receive_counters() const {
  return bus_.impl_->receiver ? bus_.impl_->receiver->counters() : UdpmCounters{};
}

AuthCounters BusState::auth_counters() const { return bus_.impl_->auth->counters(); }

int64_t BusState::live_peers() const { return bus_.impl_->auth->answered(); }

double BusState::auth_seconds() const { return bus_.impl_->auth->seconds(); }

const DecodeLimits& Bus::decode_limits() const { return impl_->options.decode_limits; }

void Bus::PublishBytes(const std::string& channel, const uint8_t* data, size_t size) {
  if (impl_->Drop(impl_->options.drop_publish_fraction, channel)) return;
  if (impl_->auth->keyed()) {
    impl_->auth->Seal(channel, data, size, &impl_->sealed);
    data = impl_->sealed.data();
    size = impl_->sealed.size();
  }
  if (impl_->sender) {
    impl_->sender->Send(channel, data, size);
  } else if (impl_->lcm->publish(channel, data, static_cast<unsigned int>(size)) != 0) {
    throw std::runtime_error("cannot publish " + std::to_string(size) + " bytes on channel " +
                             channel + " (" + impl_->url + ")");
  }
}

Subscription Bus::SubscribeBytes(const std::string& channel, BytesHandler handler,
                                 int queue_capacity) {
  auto slot = std::make_shared<Subscription::Slot>();
  slot->handler = std::make_shared<BytesHandler>(std::move(handler));
  Subscription subscription{std::weak_ptr<Subscription::Slot>(slot)};
  // a second handler on a channel joins the first subscription (the larger queue wins)
  if (Impl::Subscriber* subscriber = impl_->Find(channel)) {
    subscriber->handlers.push_back(std::move(slot));
    if (queue_capacity > subscriber->queue_capacity) {
      subscriber->queue_capacity = queue_capacity;
      if (subscriber->subscription != nullptr) {
        subscriber->subscription->setQueueCapacity(queue_capacity);
      }
      if (impl_->receiver) impl_->receiver->Subscribe(channel, queue_capacity);
    }
    return subscription;
  }
  impl_->subscribers.push_back(Impl::Subscriber{impl_.get(), channel, {std::move(slot)}});
  Impl::Subscriber& subscriber = impl_->subscribers.back();
  subscriber.queue_capacity = queue_capacity;
  if (impl_->receiver) {
    impl_->receiver->Subscribe(channel, queue_capacity);
    return subscription;
  }
  // lcm treats the channel as a regular expression; ours are plain names.
  subscriber.subscription = impl_->lcm->subscribeFunction(channel, &Impl::Dispatch, &subscriber);
  if (subscriber.subscription == nullptr) {
    impl_->subscribers.pop_back();
    throw std::runtime_error("cannot subscribe to channel " + channel);
  }
  subscriber.subscription->setQueueCapacity(queue_capacity);
  return subscription;
}

int Bus::HandleFor(int timeout_ms) {
  using Clock = std::chrono::steady_clock;
  const Clock::time_point deadline = Clock::now() + std::chrono::milliseconds(timeout_ms);
  int handled = 0;
  while (true) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    const int wait_ms = static_cast<int>(std::max<int64_t>(0, left.count()));
    if (impl_->receiver) {
      // udpm://: messages already checked and reassembled by the receiver's thread
      UdpmMessage message;
      const UdpmReceiver::Taken taken = impl_->receiver->Take(wait_ms, &message);
      if (taken != UdpmReceiver::Taken::kMessage) break;  // a timeout, or a signal
      if (Impl::Subscriber* subscriber = impl_->Find(message.channel)) {
        impl_->Deliver(subscriber, message.data.get(), message.size, true);
      }
    } else {
      const int result = impl_->lcm->handleTimeout(wait_ms);
      // a signal (e.g. SIGINT for a clean stop) ends the wait like a timeout.
      if (result < 0 && errno == EINTR) break;
      // the end of a file:// log: nothing more will come
      if (result < 0 && impl_->url.rfind("file://", 0) == 0) {
        impl_->log_ended = true;
        break;
      }
      if (result < 0) {
        throw std::runtime_error("LCM failed while handling messages on " + impl_->url);
      }
      if (result == 0) break;
    }
    ++handled;
    if (impl_->pending_error) {
      std::exception_ptr error = impl_->pending_error;
      impl_->pending_error = nullptr;
      std::rethrow_exception(error);
    }
  }
  return handled;
}

}  // namespace stackgen
