#include "stitch/sync/policy.hpp"

#include <algorithm>

namespace stitch::sync {

namespace {

std::string ms(int64_t ns) { return std::to_string(ns / 1000000) + " ms"; }

}  // namespace

bool update_dropout(DropoutTrack& track, const InputFacts& in, int64_t now, int64_t started, int64_t timeout,
                    std::string& reason) {
  reason.clear();
  if (in.has_frame) track.ever_had_frame = true;
  const bool stale = in.has_frame && now != kNoTime && in.frame_end != kNoTime && now > in.frame_end &&
                     now - in.frame_end > timeout;
  if (track.dropped) {
    // out until a fresh frame covers the output: frames queued for later (a reconnect's new
    // stream, a stalled camera's backlog) do not bring it back before they are shown
    if (!in.has_frame || stale) return false;
    track.dropped = false;
    return true;
  }
  if (!in.has_frame) {
    if (in.eos) {
      reason = "it ended";
    } else if (track.ever_had_frame) {
      if (!in.queued) reason = "it stopped sending frames";
    } else {
      const bool added = track.since != kNoTime && started != kNoTime && track.since > started;
      const int64_t from = added ? track.since : started;
      if (now != kNoTime && from != kNoTime && now >= from && now - from > timeout)
        reason = in.negotiated ? std::string(added ? "no frame since it was added (" : "no frame since the start (") +
                                     ms(now - from) + ")"
                               : "it never started (no caps after " + ms(now - from) + ")";
    }
  } else if (!in.queued && stale) {
    reason = "no frame for " + ms(now - in.frame_end);
  }
  const bool out = !reason.empty();
  if (out == track.dropped) return false;
  track.dropped = out;
  return true;
}

int64_t first_output_at(int64_t earliest, int64_t output, int64_t timeout) {
  if (earliest == kNoTime || output == kNoTime) return kNoTime;
  return earliest > output + timeout ? earliest : kNoTime;
}

StartDecision may_start(const std::vector<InputFacts>& inputs, int64_t waited, int64_t timeout) {
  int negotiated = 0;
  for (const InputFacts& in : inputs) negotiated += in.negotiated ? 1 : 0;
  const bool all = negotiated == int(inputs.size());
  const bool expired = waited != kNoTime && waited >= timeout;
  if (inputs.size() < 2) return expired ? StartDecision::TooFew : StartDecision::Wait;
  if (all) return StartDecision::Go;
  if (!expired) return StartDecision::Wait;
  return negotiated >= 1 ? StartDecision::Go : StartDecision::Wait;
}

bool RateLimit::allow(int64_t now, uint64_t* held_back) {
  if (last_ != kNoTime && now >= last_ && now - last_ < interval_) {
    ++suppressed_;
    return false;
  }
  if (held_back) *held_back = suppressed_;
  last_ = now;
  suppressed_ = 0;
  return true;
}

bool standin_gap_due(StandIn& s, bool live, bool delivered, int64_t since_first, int64_t timeout, int64_t output,
                     int64_t span, int64_t& start) {
  if (live || delivered || since_first == kNoTime || since_first < timeout || span <= 0) return false;
  const int64_t out = output == kNoTime ? 0 : output;
  if (s.sent_until != kNoTime && s.sent_until >= out + span) return false;  // far enough ahead
  start = s.sent_until == kNoTime ? 0 : std::max(s.sent_until, out);
  s.sent_until = start + span;
  return true;
}

}  // namespace stitch::sync
