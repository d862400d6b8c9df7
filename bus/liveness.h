#pragma once

// The liveness check of the bus key (auth.h, docs/design.md, "Trust"): replays are bound to the run,
// not to a time window. A keyed process on a live bus takes a sender's messages only once that
// sender has answered a challenge drawn now, and only what it signed after its answer:
//
// - starting, a process challenges every process (responder 0) on STACKGEN_LIVENESS;
// - hearing a verified message of a sender that has not answered, it drops the message and
//   challenges that sender (again at most every kRechallengeS while it keeps sending);
// - hearing a challenge for itself or for every process, it answers at once with the nonce, and
//   challenges the challenger in turn when that one has not answered it;
// - hearing an answer to one of its nonces from the process it asked, it takes that sender's
//   messages signed after the answer (MessageAuth::Proven).
//
// Everything on STACKGEN_LIVENESS is signed and verified like any message (a stranger cannot
// answer); a recording played back cannot answer a nonce drawn after it was made, and what it
// holds of a sender that still runs was signed before that sender's answer. A sender that keeps
// sending without answering for kUnansweredS (a recording) has its messages counted as replayed,
// with one warning. Memory: at most kMaxChallenged senders are challenged at a time. All calls
// come from one thread (a Bus's receiving thread); time is passed in, so tests drive it.

#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <set>
#include <string>
#include <utility>

#include <stackgen/liveness.hpp>

#include "bus/auth.h"
#include "bus/channels.h"

namespace stackgen {

/// Runs the liveness check of one keyed Bus on a live bus (see the file comment).
class LivenessCheck {
 public:
  /// A sender that has not answered is challenged again after this long (seconds).
  static constexpr double kRechallengeS = 0.25;
  /// A sender that keeps sending without answering for this long is taken for a recording: its
  /// messages are counted as replayed, with one warning (seconds).
  static constexpr double kUnansweredS = 2.0;
  /// ... and said (once) when it has not answered for this long: on a link that loses most
  /// datagrams a live sender's answer can take longer than kUnansweredS (seconds).
  static constexpr double kWarnUnansweredS = 10.0;
  /// Senders challenged and not answered yet, remembered at most.
  static constexpr size_t kMaxChallenged = 1024;
  /// Challenges answered, remembered (by sender and counter) so that a repeat of one (a replay)
  /// is not answered again.
  static constexpr size_t kMaxAnswered = 4096;
  /// Challenges answered per second at most, in bursts of as many (a bus of a few hundred
  /// processes challenges this one a few times each at its start; a stranger's flood of
  /// recorded or fresh challenges costs an answer each no faster than this).
  static constexpr double kAnswersPerS = 200;

  /// Publishes a liveness message (signed by the caller's Bus).
  using Send = std::function<void(const liveness& message)>;
  /// Receives one warning line.
  using Warn = std::function<void(const std::string& line)>;

  /// `auth` (keyed) must outlive the check; `nonce` draws the random nonces (OpenSSL's
  /// RAND_bytes in a Bus).
  LivenessCheck(MessageAuth* auth, Send send, Warn warn, std::function<int64_t()> nonce);

  /// Challenges every process (a process's first message).
  void Start(int64_t now_us);

  /// A verified liveness message whose trailer names `from` and `counter`.
  void Handle(const liveness& message, uint64_t from, uint64_t counter, int64_t now_us);

  /// A verified message on `channel` of `sender`, which has not answered: challenges it when
  /// due; once it has not answered for kUnansweredS, counts the message as replayed.
  void Unanswered(uint64_t sender, const std::string& channel, int64_t now_us);

  /// Challenges sent and answers sent so far; challenges not answered: repeats of one answered
  /// already, and those beyond kAnswersPerS.
  int64_t challenges() const { return challenges_; }
  int64_t answers() const { return answers_; }
  int64_t repeats() const { return repeats_; }
  int64_t throttled() const { return throttled_; }

 private:
  struct Challenged {
    int64_t nonce = 0;
    int64_t first_us = 0;
    int64_t last_us = 0;
  };
  void Challenge(uint64_t responder, int64_t now_us);

  MessageAuth* auth_;
  Send send_;
  Warn warn_;
  std::function<int64_t()> nonce_;
  int64_t start_nonce_ = 0;
  std::map<uint64_t, Challenged> challenged_;
  bool warned_ = false;
  int64_t challenges_ = 0;
  int64_t answers_ = 0;
  std::set<std::pair<uint64_t, uint64_t>> answered_;  // (challenger, counter)
  std::deque<std::pair<uint64_t, uint64_t>> answered_order_;
  double tokens_ = kAnswersPerS;
  int64_t tokens_us_ = 0;
  int64_t repeats_ = 0;
  int64_t throttled_ = 0;
};

}  // namespace stackgen
