#include "session/delivery.h"

#include <algorithm>
#include <chrono>
#include <deque>
#include <map>
#include <set>
#include <stdexcept>
#include <utility>

#include <openssl/evp.h>
#include <stackgen/credit.hpp>
#include <stackgen/resend_request.hpp>

#include "bus/channels.h"
#include "contract/scene_contract.h"

namespace stackgen {
namespace {

using TimePoint = Clock::TimePoint;

// the most seqs one resend request carries
constexpr int kMaxSeqsPerRequest = 256;
// the largest window a consumer may offer (stackgen-coco's and the feed's --window limit); a
// credit offering more, or less than 0, is refused
constexpr int32_t kMaxWindow = 10000;
// the longest consumer name taken (stackgen-coco's holds its host and dataset folder)
constexpr size_t kMaxConsumerName = 4096;
// consumers held off for offering no window, remembered at most
constexpr size_t kMaxHeldOff = 1024;
// a consumer not heard for this long is not listening (paused, stopped): its tail is not resent
// (credits come every 0.2 s)
constexpr double kListeningS = 1.0;
// tail resends to a consumer that took none of the last back off, doubling up to this
constexpr double kMaxTailResendIntervalS = 5.0;

double SecondsSince(TimePoint then, TimePoint now) {
  return std::chrono::duration<double>(now - then).count();
}

}  // namespace

std::string RunName(int64_t base_seed, const std::string& config_path,
                    const std::string& config_pbtxt) {
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int length = 0;
  if (EVP_Digest(config_pbtxt.data(), config_pbtxt.size(), digest, &length, EVP_sha256(),
                 nullptr) != 1) {
    throw std::runtime_error("OpenSSL cannot compute a SHA-256");
  }
  std::string hex;
  const char* digits = "0123456789abcdef";
  for (unsigned int i = 0; i < 8 && i < length; ++i) {
    hex += digits[digest[i] >> 4];
    hex += digits[digest[i] & 15];
  }
  return "seed " + std::to_string(base_seed) + ", config " + config_path + " (sha256 " + hex + ")";
}

bool SameRun(const std::string& a, const std::string& b) {
  // the seed (up to the first comma) and the digest (the last parenthesis) of each
  const auto key = [](const std::string& run) -> std::string {
    const size_t comma = run.find(',');
    const size_t digest = run.rfind(" (sha256 ");
    if (run.rfind("seed ", 0) != 0 || comma == std::string::npos || digest == std::string::npos ||
        digest < comma) {
      return run;
    }
    return run.substr(0, comma) + run.substr(digest);
  };
  return key(a) == key(b);
}

// ---------------------------------------------------------------------------------------------
// SceneServer

struct SceneServer::Impl {
  // what the generator knows of one reliable consumer
  struct Consumer {
    bool addressed = false;  // it has sent a credit for this generator (not only the wildcard)
    int64_t stored_through = -1;
    int64_t last_received = -1;
    int32_t window = 0;
    TimePoint last_heard;
    TimePoint last_tail_resend;
    // when last_received last grew; tail resends since then (each waits twice the one before)
    TimePoint last_progress;
    int tail_resends = 0;
    // scenes sent again while it lacked them, since it last progressed (stalled())
    int64_t resent_since_progress = 0;
    // since when it offers no window (window 0), if it does
    std::optional<TimePoint> closed_since;
  };
  // a published scene kept for resending
  struct Kept {
    int64_t seq = 0;
    std::vector<uint8_t> bytes;
  };

  Bus* bus = nullptr;
  SceneServerOptions options;
  Clock* clock = nullptr;         // options.clock, or the steady clock
  Subscription subscriptions[2];  // credits and resend requests, ended with the server
  Regenerate regenerate;
  Notice notice;
  std::map<std::string, Consumer> consumers;
  // consumers dropped for offering no window longer than the consumer timeout: not registered
  // again until a credit offers one
  std::set<std::string> held_off;
  std::deque<Kept> ring;
  int64_t next_seq = -1;  // one past the last seq published; -1 before the first
  TimePoint last_publish_time;
  std::set<int64_t> requested;             // seqs asked for and not served yet
  std::map<int64_t, TimePoint> resent_at;  // when a seq was last published again
  int64_t resent = 0;
  int64_t regenerated = 0;
  int64_t registrations = 0;
  std::set<std::string> gone_silent;  // dropped for silence, not registered again
  int64_t bad_messages = 0;
  std::set<std::string> refused_kinds;  // kinds of refused messages already reported
  std::string run_conflict;

  // counts a message no stackgen consumer sends and says why, once per kind
  void Refuse(const std::string& what) {
    ++bad_messages;
    if (refused_kinds.size() < 16 && refused_kinds.insert(what.substr(0, what.find(':'))).second) {
      notice("refused " + what + " (further ones are only counted)");
    }
  }

  // whether a credit is one a stackgen consumer can send; one that is not is counted and ignored
  bool CreditInRange(const credit& message) {
    if (message.consumer.empty() || message.consumer.size() > kMaxConsumerName) {
      Refuse("a credit with a consumer name of " + std::to_string(message.consumer.size()) +
             " bytes");
      return false;
    }
    if (message.stored_through_seq < -1 || message.stored_through_seq > kMaxSeq ||
        message.last_received_seq < -1 || message.last_received_seq > kMaxSeq) {
      Refuse("a credit with seqs out of range: " + message.consumer + " stored through " +
             std::to_string(message.stored_through_seq) + ", received " +
             std::to_string(message.last_received_seq));
      return false;
    }
    if (message.window < 0 || message.window > kMaxWindow) {
      Refuse("a credit with a window out of 0.." + std::to_string(kMaxWindow) + ": " +
             message.consumer + " offers " + std::to_string(message.window));
      return false;
    }
    return true;
  }

  void OnCredit(const credit& message) {
    const int32_t target = message.header.generator_id;
    if (target != options.generator_id && target != -1) return;
    if (!CreditInRange(message)) return;
    const TimePoint now = clock->Now();
    auto found = consumers.find(message.consumer);
    if (message.leaving) {
      held_off.erase(message.consumer);
      gone_silent.erase(message.consumer);
      if (found != consumers.end()) {
        consumers.erase(found);
        notice("reliable consumer " + message.consumer + " left");
      }
      return;
    }
    // a consumer holding scenes of another run must not be continued by this one
    if (!options.run.empty() && !message.run.empty() && !SameRun(message.run, options.run)) {
      ++bad_messages;
      if (run_conflict.empty()) {
        run_conflict = message.consumer + " holds scenes of generator " +
                       std::to_string(options.generator_id) + " from another run (" + message.run +
                       ") than this one (" + options.run + ")";
      }
      return;
    }
    // one that offered no window for too long registers again only with a window
    if (message.window == 0 && held_off.count(message.consumer) != 0) return;
    held_off.erase(message.consumer);
    if (found == consumers.end()) {
      found = consumers.emplace(message.consumer, Consumer{}).first;
      found->second.last_tail_resend = now;
      found->second.last_progress = now;
      notice("reliable consumer " + message.consumer + " registered");
      ++registrations;
      gone_silent.erase(message.consumer);
    }
    Consumer& consumer = found->second;
    consumer.last_heard = now;
    // a credit addressed to this generator wins over the wildcard's "nothing stored yet"
    if (target == -1 && consumer.addressed) return;
    consumer.addressed = consumer.addressed || target != -1;
    consumer.stored_through = message.stored_through_seq;
    const int64_t received = std::max(message.last_received_seq, message.stored_through_seq);
    if (received > consumer.last_received) {
      consumer.last_progress = now;
      consumer.tail_resends = 0;
      consumer.resent_since_progress = 0;
    }
    consumer.last_received = received;
    consumer.window = message.window;
    // no window (a consumer that has all it wants holds the generator until it leaves): for
    // longer than the consumer timeout, it is no longer waited for
    if (message.window > 0) {
      consumer.closed_since.reset();
    } else if (!consumer.closed_since) {
      consumer.closed_since = now;
    } else if (SecondsSince(*consumer.closed_since, now) > options.consumer_timeout_s) {
      notice("reliable consumer " + message.consumer + " has offered no window for " +
             std::to_string(static_cast<int>(SecondsSince(*consumer.closed_since, now))) +
             " s: no longer waited for (it registers again once it offers one)");
      consumers.erase(found);
      if (held_off.size() >= kMaxHeldOff) held_off.erase(held_off.begin());
      held_off.insert(message.consumer);
    }
  }

  // only a registered consumer's requests, and only for seqs it can take (its window): a stray
  // request cannot make the generator regenerate its whole history
  void OnResend(const resend_request& message) {
    if (message.header.generator_id != options.generator_id) return;
    // what no SceneClient sends: too many seqs, not ascending, never published
    const int64_t last_published = next_seq - 1;
    if (message.seqs.size() > static_cast<size_t>(kMaxSeqsPerRequest)) {
      Refuse("a resend request for " + std::to_string(message.seqs.size()) + " seqs (at most " +
             std::to_string(kMaxSeqsPerRequest) + ") from " + message.consumer);
      return;
    }
    for (size_t i = 0; i < message.seqs.size(); ++i) {
      const int64_t seq = message.seqs[i];
      if (seq < 0 || seq > last_published || (i > 0 && seq <= message.seqs[i - 1])) {
        Refuse("a resend request for seqs not ascending or never published (" +
               std::to_string(seq) + "; published up to " + std::to_string(last_published) +
               ") from " + message.consumer);
        return;
      }
    }
    const auto found = consumers.find(message.consumer);
    if (found == consumers.end()) return;
    const Consumer& consumer = found->second;
    // only seqs it has not stored and can take: a request cannot make the generator regenerate
    // its history
    const int64_t last =
        std::min(last_published, consumer.stored_through + std::max<int64_t>(1, consumer.window));
    for (const int64_t seq : message.seqs) {
      if (seq > consumer.stored_through && seq <= last) requested.insert(seq);
    }
  }

  // publishes `seq` again, from the ring or regenerated
  void Serve(int64_t seq, TimePoint now) {
    const auto sent = resent_at.find(seq);
    if (sent != resent_at.end() &&
        SecondsSince(sent->second, now) < options.min_resend_interval_s) {
      return;
    }
    const auto kept = std::find_if(ring.begin(), ring.end(),
                                   [seq](const Kept& entry) { return entry.seq == seq; });
    if (kept != ring.end()) {
      bus->PublishEncoded(kSceneChannel, kept->bytes);
      ++resent;
    } else {
      bus->PublishEncoded(kSceneChannel, regenerate(seq));
      ++regenerated;
    }
    resent_at[seq] = clock->Now();
    for (auto& [name, consumer] : consumers) {
      if (consumer.stored_through < seq) ++consumer.resent_since_progress;
    }
  }
};

SceneServer::SceneServer(Bus* bus, const SceneServerOptions& options, Regenerate regenerate,
                         Notice notice)
    : impl_(std::make_unique<Impl>()) {
  if (options.ring_size < 1) throw std::invalid_argument("the resend ring needs >= 1 scene");
  if (!(options.consumer_timeout_s > 0)) {
    throw std::invalid_argument("the consumer timeout must be > 0 s");
  }
  impl_->bus = bus;
  impl_->options = options;
  impl_->clock = options.clock != nullptr ? options.clock : &SteadyClock();
  impl_->regenerate = std::move(regenerate);
  impl_->notice = std::move(notice);
  Impl* impl = impl_.get();
  const auto count_bad = [impl](const std::string&) { ++impl->bad_messages; };
  impl->subscriptions[0] =
      bus->Subscribe<credit>(
             kCreditChannel, [impl](const credit& message) { impl->OnCredit(message); }, 1000,
             count_bad)
          .EndWhenDropped();
  impl->subscriptions[1] =
      bus->Subscribe<resend_request>(
             kResendChannel, [impl](const resend_request& message) { impl->OnResend(message); },
             1000, count_bad)
          .EndWhenDropped();
}

SceneServer::~SceneServer() = default;

void SceneServer::Publish(int64_t seq, std::vector<uint8_t> encoded_scene) {
  if (impl_->next_seq >= 0 && seq != impl_->next_seq) {
    throw std::logic_error("SceneServer::Publish: seq " + std::to_string(seq) + " after " +
                           std::to_string(impl_->next_seq - 1));
  }
  impl_->bus->PublishEncoded(kSceneChannel, encoded_scene);
  impl_->last_publish_time = impl_->clock->Now();
  impl_->next_seq = seq + 1;
  impl_->ring.push_back(Impl::Kept{seq, std::move(encoded_scene)});
  while (static_cast<int>(impl_->ring.size()) > impl_->options.ring_size) impl_->ring.pop_front();
}

bool SceneServer::MayPublish(int64_t seq) const {
  for (const auto& [name, consumer] : impl_->consumers) {
    if (seq > consumer.stored_through + consumer.window) return false;
  }
  return true;
}

void SceneServer::Service(int timeout_ms) {
  Impl& impl = *impl_;
  impl.bus->HandleFor(timeout_ms);
  const TimePoint now = impl.clock->Now();

  // drop consumers that went silent
  for (auto it = impl.consumers.begin(); it != impl.consumers.end();) {
    const double silent_s = SecondsSince(it->second.last_heard, now);
    if (silent_s > impl.options.consumer_timeout_s) {
      impl.notice("reliable consumer " + it->first + " silent for " +
                  std::to_string(static_cast<int>(silent_s)) +
                  " s: no longer waited for (it registers again with its next credit)");
      if (impl.gone_silent.size() < kMaxHeldOff) impl.gone_silent.insert(it->first);
      it = impl.consumers.erase(it);
    } else {
      ++it;
    }
  }

  // unreceived tails: what a consumer can take but has not received a while after publication
  const int64_t last_published = impl.next_seq - 1;
  if (last_published >= 0 &&
      SecondsSince(impl.last_publish_time, now) >= impl.options.tail_resend_s) {
    for (auto& [name, consumer] : impl.consumers) {
      if (consumer.last_received >= last_published) continue;
      // not listening (paused or stopped: no credit for a while): nothing is resent to it
      if (SecondsSince(consumer.last_heard, now) > kListeningS) continue;
      // a consumer still taking scenes in has them queued, not lost: wait until it stops
      // progressing; each resend it takes nothing from doubles the wait for the next
      const double wait_s =
          std::min(kMaxTailResendIntervalS,
                   impl.options.tail_resend_s *
                       static_cast<double>(1 << std::min(consumer.tail_resends, 16)));
      if (SecondsSince(consumer.last_tail_resend, now) < wait_s ||
          SecondsSince(consumer.last_progress, now) < impl.options.tail_resend_s) {
        continue;
      }
      const int64_t last = std::min(last_published, consumer.stored_through + consumer.window);
      for (int64_t seq = consumer.last_received + 1; seq <= last; ++seq) {
        impl.requested.insert(seq);
      }
      consumer.last_tail_resend = now;
      ++consumer.tail_resends;
    }
  }

  // serve, oldest first; forget send times long past
  const std::set<int64_t> due = std::move(impl.requested);
  impl.requested.clear();
  for (const int64_t seq : due) impl.Serve(seq, now);
  for (auto it = impl.resent_at.begin(); it != impl.resent_at.end();) {
    it = SecondsSince(it->second, now) > 10 ? impl.resent_at.erase(it) : std::next(it);
  }
}

std::string SceneServer::stalled() const {
  const Impl& impl = *impl_;
  const TimePoint now = impl.clock->Now();
  for (const auto& [name, consumer] : impl.consumers) {
    const double stalled_s = SecondsSince(consumer.last_progress, now);
    if (consumer.resent_since_progress == 0 || stalled_s < impl.options.stall_timeout_s ||
        SecondsSince(consumer.last_heard, now) > kListeningS ||
        consumer.stored_through >= impl.next_seq - 1) {
      continue;
    }
    return "reliable consumer " + name + " has received none of the scenes it lacks (from seq " +
           std::to_string(consumer.stored_through + 1) + ") for " +
           std::to_string(static_cast<int>(stalled_s)) + " s though it still credits and they " +
           "were sent again " + std::to_string(consumer.resent_since_progress) +
           " times: the bus loses them on the way (between hosts: frame loss with a large mtu= " +
           "in the URL, a firewall or a full receive buffer; docs/operations.md, Across hosts)";
  }
  return "";
}

bool SceneServer::AllStoredThrough(int64_t last_seq) const {
  for (const auto& [name, consumer] : impl_->consumers) {
    if (consumer.stored_through < last_seq) return false;
  }
  return true;
}

std::optional<int64_t> SceneServer::ResumeSeq() const {
  std::optional<int64_t> seq;
  for (const auto& [name, consumer] : impl_->consumers) {
    const int64_t next = consumer.stored_through + 1;
    if (!seq || next < *seq) seq = next;
  }
  return seq;
}

int SceneServer::reliable_consumers() const { return static_cast<int>(impl_->consumers.size()); }
int64_t SceneServer::resent() const { return impl_->resent; }
int64_t SceneServer::registrations() const { return impl_->registrations; }
std::vector<std::string> SceneServer::gone_silent() const {
  return {impl_->gone_silent.begin(), impl_->gone_silent.end()};
}
int64_t SceneServer::regenerated() const { return impl_->regenerated; }
int64_t SceneServer::bad_messages() const { return impl_->bad_messages; }
const std::string& SceneServer::run_conflict() const { return impl_->run_conflict; }

// ---------------------------------------------------------------------------------------------
// SceneClient

struct SceneClient::Impl {
  // what the consumer knows of one generator's stream
  struct Stream {
    int64_t stored_through = -1;
    std::set<int64_t> done_above;  // stored or skipped seqs (of this shard) above stored_through
    // received and handed to the consumer, neither stored nor skipped yet (a writer's group
    // waiting for its commit, a learner's queue): not missing, never asked for again
    std::set<int64_t> pending;
    int64_t last_received = -1;
    std::map<int64_t, TimePoint> asked;  // missing seq -> when last asked for
    bool credit_due = true;
    std::string run;  // the RunName its scenes come from ("": unknown)
  };

  Bus* bus = nullptr;
  SceneClientOptions options;
  Clock* clock = nullptr;  // options.clock, or the steady clock
  std::map<int32_t, Stream> streams;
  DeliveryCounters counters;
  int64_t stored_total = 0;  // stored, restored ones included (not skipped ones)
  TimePoint last_credit;
  bool left = false;

  // whether scenes of `generator_id` are tracked at all
  bool Tracked(int32_t generator_id) const {
    if (generator_id < 0 || generator_id > kMaxGeneratorId) return false;
    const std::vector<int32_t>& ids = options.generator_ids;
    return ids.empty() || std::find(ids.begin(), ids.end(), generator_id) != ids.end();
  }

  // whether the wildcard credit is sent (a writer of every generator)
  bool Wildcard() const { return options.generator_ids.empty() && !options.join_where_heard; }

  // whether `seq` belongs to this consumer's shard (and is not below its first seq)
  bool InShard(int64_t seq) const {
    return seq >= options.first_seq && seq % options.shard_count == options.shard_index;
  }

  // seqs of this shard in first_seq..seq
  int64_t ShardSeqsThrough(int64_t seq) const {
    const auto through = [this](int64_t last) -> int64_t {
      if (last < options.shard_index) return 0;
      return (last - options.shard_index) / options.shard_count + 1;
    };
    return std::max<int64_t>(0, through(seq) - through(options.first_seq - 1));
  }

  // moves stored_through over every seq that is done: stored, skipped or of another shard
  static void Advance(const Impl& impl, Stream& stream) {
    while (true) {
      const int64_t next = stream.stored_through + 1;
      if (!stream.done_above.empty() && *stream.done_above.begin() == next) {
        stream.done_above.erase(stream.done_above.begin());
      } else if (impl.InShard(next) || next > kMaxSeq) {
        break;
      }
      ++stream.stored_through;
    }
  }

  // the stream of `generator_id`, created (with other shards' first seqs done) when new;
  // `heard_seq` is the seq that makes a learner create it (join_where_heard)
  Stream& StreamOf(int32_t generator_id, int64_t heard_seq = -1) {
    const auto found = streams.find(generator_id);
    if (found != streams.end()) return found->second;
    Stream& stream = streams[generator_id];
    stream.stored_through = options.first_seq - 1;
    stream.last_received = options.first_seq - 1;
    if (options.join_where_heard && heard_seq > options.window &&
        heard_seq - 1 > stream.stored_through) {
      stream.stored_through = heard_seq - 1;
      stream.last_received = heard_seq - 1;
    }
    Advance(*this, stream);
    return stream;
  }

  // true when `seq` was not done before
  bool MarkDone(int32_t generator_id, int64_t seq) {
    Stream& stream = StreamOf(generator_id);
    stream.pending.erase(seq);
    if (seq <= stream.stored_through || !stream.done_above.insert(seq).second) return false;
    stream.asked.erase(seq);
    Advance(*this, stream);
    stream.last_received = std::max(stream.last_received, seq);
    stream.credit_due = true;
    return true;
  }

  // how many scenes past stored_through a generator may publish now
  int32_t Window() const {
    int64_t window = options.window;
    if (options.max_scenes > 0) window = std::min(window, options.max_scenes - stored_total);
    return static_cast<int32_t>(std::max<int64_t>(0, window));
  }

  void SendCredit(int32_t generator_id, int64_t stored_through, int64_t last_received,
                  bool leaving) {
    credit message{};
    message.header.seq = -1;
    message.stored_through_seq = stored_through;
    message.header.generator_id = generator_id;
    message.header.utime = UnixMicros();
    message.consumer = options.name;
    message.window = Window();
    message.last_received_seq = last_received;
    message.leaving = leaving;
    if (generator_id >= 0) {
      const auto stream = streams.find(generator_id);
      if (stream != streams.end()) message.run = stream->second.run;
    }
    bus->Publish(kCreditChannel, message);
  }
};

SceneClient::SceneClient(Bus* bus, const SceneClientOptions& options)
    : impl_(std::make_unique<Impl>()) {
  if (options.name.empty()) throw std::invalid_argument("a reliable consumer needs a name");
  if (options.window < 1) throw std::invalid_argument("the window must be >= 1 scene");
  if (options.max_scenes < 0) throw std::invalid_argument("max_scenes must be >= 0");
  if (options.shard_count < 1 || options.shard_count > kMaxShards) {
    throw std::invalid_argument("a stream splits into 1.." + std::to_string(kMaxShards) +
                                " shards, not " + std::to_string(options.shard_count));
  }
  if (options.first_seq < 0 || options.first_seq > kMaxSeq) {
    throw std::invalid_argument("the first seq must be in 0.." + std::to_string(kMaxSeq) +
                                ", not " + std::to_string(options.first_seq));
  }
  if (options.shard_index < 0 || options.shard_index >= options.shard_count) {
    throw std::invalid_argument("shard " + std::to_string(options.shard_index) +
                                " is not one of 0.." + std::to_string(options.shard_count - 1));
  }
  for (const int32_t generator_id : options.generator_ids) {
    if (generator_id < 0 || generator_id > kMaxGeneratorId) {
      throw std::invalid_argument("generator id " + std::to_string(generator_id) +
                                  " is outside 0.." + std::to_string(kMaxGeneratorId));
    }
  }
  impl_->bus = bus;
  impl_->options = options;
  impl_->clock = options.clock != nullptr ? options.clock : &SteadyClock();
  impl_->last_credit = impl_->clock->Now() - std::chrono::hours(1);
  // listed generators are credited from the start (a learner's once heard): no wildcard
  if (!options.join_where_heard) {
    for (const int32_t generator_id : options.generator_ids) impl_->StreamOf(generator_id);
  }
}

SceneClient::~SceneClient() = default;

void SceneClient::Restore(int32_t generator_id, const std::vector<int64_t>& seqs) {
  if (!impl_->Tracked(generator_id)) return;
  for (const int64_t seq : seqs) {
    if (seq >= 0 && seq <= kMaxSeq && impl_->InShard(seq) && impl_->MarkDone(generator_id, seq)) {
      ++impl_->stored_total;
    }
  }
}

void SceneClient::SetRun(int32_t generator_id, const std::string& run) {
  if (!impl_->Tracked(generator_id)) return;
  Impl::Stream& stream = impl_->StreamOf(generator_id);
  if (stream.run != run) stream.credit_due = true;
  stream.run = run;
}

bool SceneClient::Received(int32_t generator_id, int64_t seq) {
  if (!impl_->Tracked(generator_id) || !SceneIdsInRange(generator_id, seq)) return false;
  Impl::Stream& stream = impl_->StreamOf(generator_id, seq);
  // another shard's scene: it only shows how far the generator has got
  if (!impl_->InShard(seq)) {
    if (seq > stream.last_received) {
      stream.last_received = seq;
      stream.credit_due = true;
    }
    return false;
  }
  ++impl_->counters.received;
  if (seq <= stream.stored_through || stream.done_above.count(seq) != 0) {
    ++impl_->counters.duplicates;
    return false;
  }
  if (seq > stream.last_received) {
    stream.last_received = seq;
    stream.credit_due = true;
  }
  if (!stream.pending.insert(seq).second) {
    // handed over already and not yet stored or skipped: a repeat all the same
    ++impl_->counters.duplicates;
    return false;
  }
  stream.asked.erase(seq);
  return true;
}

void SceneClient::Stored(int32_t generator_id, int64_t seq) {
  if (!impl_->Tracked(generator_id) || !SceneIdsInRange(generator_id, seq) || !impl_->InShard(seq))
    return;
  ++impl_->counters.stored;
  ++impl_->stored_total;
  impl_->MarkDone(generator_id, seq);
}

void SceneClient::Skipped(int32_t generator_id, int64_t seq) {
  if (!impl_->Tracked(generator_id) || !SceneIdsInRange(generator_id, seq) || !impl_->InShard(seq))
    return;
  impl_->MarkDone(generator_id, seq);
}

void SceneClient::Service() {
  Impl& impl = *impl_;
  if (impl.left) return;
  const TimePoint now = impl.clock->Now();
  const bool period_due = SecondsSince(impl.last_credit, now) >= impl.options.credit_period_s;

  for (auto& [generator_id, stream] : impl.streams) {
    // credits: at once after a change, else every period
    if (stream.credit_due || period_due) {
      impl.SendCredit(generator_id, stream.stored_through, stream.last_received, false);
      stream.credit_due = false;
    }

    // missing seqs below the highest received, as far as the window reaches
    const int64_t last =
        std::min(stream.last_received, stream.stored_through + std::max<int64_t>(1, impl.Window()));
    std::vector<int64_t> ask;
    for (int64_t seq = stream.stored_through + 1;
         seq <= last && static_cast<int>(ask.size()) < kMaxSeqsPerRequest; ++seq) {
      if (!impl.InShard(seq) || stream.done_above.count(seq) != 0 ||
          stream.pending.count(seq) != 0) {
        continue;
      }
      const auto asked = stream.asked.find(seq);
      if (asked != stream.asked.end() &&
          SecondsSince(asked->second, now) < impl.options.reask_after_s) {
        continue;
      }
      stream.asked[seq] = now;
      ask.push_back(seq);
    }
    if (!ask.empty()) {
      resend_request request{};
      request.header.seq = -1;
      request.header.generator_id = generator_id;
      request.header.utime = UnixMicros();
      request.consumer = impl.options.name;
      request.num_seqs = static_cast<int32_t>(ask.size());
      request.seqs = ask;
      impl.bus->Publish(kResendChannel, request);
      impl.counters.reasked += static_cast<int64_t>(ask.size());
    }
  }

  // the wildcard: generators not heard from yet count this consumer as having stored nothing
  // below its first seq (not with a list of generators: those are credited by name, and others
  // must not wait)
  if (period_due) {
    const int64_t before_first = impl.options.first_seq - 1;
    if (impl.Wildcard()) impl.SendCredit(-1, before_first, before_first, false);
    impl.last_credit = now;
  }
}

void SceneClient::Leave() {
  Impl& impl = *impl_;
  if (impl.left) return;
  for (const auto& [generator_id, stream] : impl.streams) {
    impl.SendCredit(generator_id, stream.stored_through, stream.last_received, true);
  }
  const int64_t before_first = impl.options.first_seq - 1;
  if (impl.Wildcard()) impl.SendCredit(-1, before_first, before_first, true);
  // once more: a lost last credit would keep a generator waiting for the whole timeout
  for (const auto& [generator_id, stream] : impl.streams) {
    impl.SendCredit(generator_id, stream.stored_through, stream.last_received, true);
  }
  if (impl.Wildcard()) impl.SendCredit(-1, before_first, before_first, true);
  impl.left = true;
}

int64_t SceneClient::StoredThrough(int32_t generator_id) const {
  const auto found = impl_->streams.find(generator_id);
  return found == impl_->streams.end() ? -1 : found->second.stored_through;
}

DeliveryCounters SceneClient::counters() const {
  DeliveryCounters counters = impl_->counters;
  counters.lost = 0;
  // this shard's seqs between stored_through and the highest received that are not done
  for (const auto& [generator_id, stream] : impl_->streams) {
    const int64_t span = impl_->ShardSeqsThrough(stream.last_received) -
                         impl_->ShardSeqsThrough(stream.stored_through);
    counters.lost += std::max<int64_t>(
        0, span - static_cast<int64_t>(stream.done_above.size() + stream.pending.size()));
  }
  return counters;
}

}  // namespace stackgen
