#include "bus/liveness.h"

#include <algorithm>
#include <utility>

namespace stackgen {
namespace {

// a liveness message of `kind` from `challenger` to `responder` with `nonce`
liveness Make(int8_t kind, uint64_t challenger, uint64_t responder, int64_t nonce, int64_t now_us) {
  liveness message{};
  message.header.seq = -1;
  message.header.generator_id = -1;
  message.header.utime = now_us;
  message.kind = kind;
  message.challenger = static_cast<int64_t>(challenger);
  message.responder = static_cast<int64_t>(responder);
  message.nonce = nonce;
  return message;
}

}  // namespace

LivenessCheck::LivenessCheck(MessageAuth* auth, Send send, Warn warn,
                             std::function<int64_t()> nonce)
    : auth_(auth), send_(std::move(send)), warn_(std::move(warn)), nonce_(std::move(nonce)) {}

void LivenessCheck::Start(int64_t now_us) {
  start_nonce_ = nonce_();
  ++challenges_;
  send_(Make(liveness::CHALLENGE, auth_->sender(), 0, start_nonce_, now_us));
}

void LivenessCheck::Challenge(uint64_t responder, int64_t now_us) {
  auto found = challenged_.find(responder);
  if (found == challenged_.end()) {
    // a full table: the oldest challenge is given up (its sender is challenged anew when heard)
    if (challenged_.size() >= kMaxChallenged) {
      auto oldest = challenged_.begin();
      for (auto it = challenged_.begin(); it != challenged_.end(); ++it) {
        if (it->second.last_us < oldest->second.last_us) oldest = it;
      }
      challenged_.erase(oldest);
    }
    Challenged fresh;
    fresh.nonce = nonce_();
    fresh.first_us = now_us;
    fresh.last_us = now_us - static_cast<int64_t>(kRechallengeS * 1e6) - 1;
    found = challenged_.emplace(responder, fresh).first;
  }
  Challenged& challenged = found->second;
  if (now_us - challenged.last_us <= static_cast<int64_t>(kRechallengeS * 1e6)) return;
  challenged.last_us = now_us;
  ++challenges_;
  send_(Make(liveness::CHALLENGE, auth_->sender(), responder, challenged.nonce, now_us));
}

void LivenessCheck::Handle(const liveness& message, uint64_t from, uint64_t counter,
                           int64_t now_us) {
  const uint64_t self = auth_->sender();
  if (from == self) return;  // our own, heard back
  const auto responder = static_cast<uint64_t>(message.responder);
  const auto challenger = static_cast<uint64_t>(message.challenger);
  if (message.kind == liveness::CHALLENGE) {
    // a challenge must come from the challenger it names
    if (challenger != from || (responder != 0 && responder != self)) return;
    // a challenge heard before (its sender's counter: a replay) is not answered again; a real
    // challenger asks again in a message of its own
    if (!answered_.emplace(from, counter).second) {
      ++repeats_;
      return;
    }
    answered_order_.emplace_back(from, counter);
    if (answered_order_.size() > kMaxAnswered) {
      answered_.erase(answered_order_.front());
      answered_order_.pop_front();
    }
    // and no more than kAnswersPerS a second: an unanswered challenger asks again
    if (tokens_us_ != 0) {
      tokens_ = std::min(kAnswersPerS, tokens_ + (now_us - tokens_us_) * 1e-6 * kAnswersPerS);
    }
    tokens_us_ = now_us;
    if (tokens_ < 1) {
      ++throttled_;
      return;
    }
    tokens_ -= 1;
    ++answers_;
    send_(Make(liveness::ANSWER, challenger, self, message.nonce, now_us));
    // and the challenger in turn, so that its messages are taken from its first one on
    if (!auth_->Live(from)) Challenge(from, now_us);
    return;
  }
  if (message.kind != liveness::ANSWER || challenger != self || responder != from) return;
  const auto found = challenged_.find(from);
  const bool ours = message.nonce == start_nonce_ ||
                    (found != challenged_.end() && message.nonce == found->second.nonce);
  if (!ours) return;  // an answer to a nonce of another run: a recording
  auth_->Proven(from, counter);
  if (found != challenged_.end()) challenged_.erase(found);
}

void LivenessCheck::Unanswered(uint64_t sender, const std::string& channel, int64_t now_us) {
  Challenge(sender, now_us);
  const auto found = challenged_.find(sender);
  if (found == challenged_.end()) return;
  if (now_us - found->second.first_us < static_cast<int64_t>(kUnansweredS * 1e6)) return;
  auth_->CountUnanswered();
  if (!warned_ && now_us - found->second.first_us >= static_cast<int64_t>(kWarnUnansweredS * 1e6)) {
    warned_ = true;
    warn_("refusing the messages on " + channel + " of a sender that has not answered the " +
          "liveness check of the bus key for " + std::to_string(static_cast<int>(kWarnUnansweredS)) +
          " s (sender " + KeyIdText(sender) +
          "): a recording played back onto the bus (or a link that loses most datagrams)? A "
          "consumer takes a recording with --replay; further ones are only counted (status: "
          "refused_replayed)");
  }
}

}  // namespace stackgen
