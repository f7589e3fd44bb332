// Start-up and dropout policy of stitchsync, without GStreamer: when the first bundle may go
// out, and when a camera has dropped out or is back. The element gathers each input's facts at
// an output time (InputFacts), keeps one DropoutTrack per input (on the pad), and turns the
// decisions into bus messages.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace stitch::sync {

constexpr int64_t kNoTime = -1;

// What the element knows of one input when it makes an output at running time `now`.
struct InputFacts {
  bool negotiated = false;  // the input has caps
  bool has_frame = false;   // a frame covers (or precedes) this output
  bool queued = false;      // a later frame already waits: a timestamp gap, not a stall
  bool eos = false;         // the input ended
  int64_t frame_end = kNoTime;  // running time at which its current frame ends
};

struct DropoutTrack {
  bool dropped = false;
  bool ever_had_frame = false;
  // running time from which a camera that never delivered is counted: the first bundle's
  // `started` for the cameras there from the start, the output time at which the input first
  // took part for one added later (kNoTime: `started`)
  int64_t since = kNoTime;
};

// Updates `track` at output running time `now`; `started` is the running time of the first
// bundle (when the other cameras started). Returns true when the camera dropped out or came
// back, with `reason` saying why it is out (empty when it is back).
//  * an input that ended: "it ended";
//  * an input that had frames and has none now: "it stopped sending frames";
//  * an input that never delivered: out once `timeout` has passed since `started`, or since
//    `track.since` for an input added after the start;
//  * an input whose newest frame ended more than `timeout` before `now` with nothing queued
//    after it (a stalled camera). A later frame already waiting is a gap in the timestamps
//    (variable frame rate, a file with holes): never a dropout.
// A camera that is out comes back with the first fresh frame that covers an output (not with
// frames merely queued for later).
bool update_dropout(DropoutTrack& track, const InputFacts& in, int64_t now, int64_t started, int64_t timeout,
                    std::string& reason);

enum class StartDecision {
  Wait,     // an input is still negotiating: hold the first bundle
  Go,       // bundle now (inputs still without caps are left out until they start)
  TooFew,   // fewer than two inputs after the wait: an error, never a hang
};

// Before the first bundle: waits until every requested input has caps, or `timeout` has
// passed since the first input was ready (`waited`).
StartDecision may_start(const std::vector<InputFacts>& inputs, int64_t waited, int64_t timeout);

// Where a non-live output starts, from the inputs' first frames (running times; `earliest` and
// `latest` over the inputs, `output` where the output would start): at `earliest` when it lies
// more than `timeout` after `output` (cameras stamped by a capture clock: all start at, say, 100 s,
// and bundles without a frame up to there would make every camera "dropped out"); otherwise
// kNoTime, the output starts where it was going to (a closer start keeps the first bundle at zero).
int64_t first_output_at(int64_t earliest, int64_t output, int64_t timeout);
// One camera whose first frame comes this long after the earliest camera's is more likely
// stamped by another clock than started late (late cameras are a few seconds at most).
constexpr int64_t kFarApartStart = 10'000'000'000;
inline bool starts_far_apart(int64_t earliest, int64_t latest) {
  return earliest != kNoTime && latest != kNoTime && latest > earliest + kFarApartStart;
}

// A non-live input that has delivered nothing holds GstAggregator, which waits for data on every
// non-live pad: the other cameras would never go on. Once `timeout` has passed since the first
// input delivered (`since_first`, any clock), the element stands in for it with gaps (GAP events:
// "nothing for this span", which GstAggregator queues as empty GAP buffers), `span` long each and
// kept a span ahead of the output (`output`, running time; kNoTime before the first).
// A live pipeline needs none (the base class times out on its own), nor an input that delivered.
// Returns true with `start` when the next gap [start, start + span) is due.
struct StandIn {
  int64_t sent_until = kNoTime;  // running time the gaps sent so far reach
};
bool standin_gap_due(StandIn& s, bool live, bool delivered, int64_t since_first, int64_t timeout, int64_t output,
                     int64_t span, int64_t& start);

// Rate limit for repeated messages (QoS): at most one per `interval` of `now` (any clock, ns).
// When one is let through, `held_back` says how many were held back since the previous one.
class RateLimit {
 public:
  explicit RateLimit(int64_t interval) : interval_(interval) {}
  bool allow(int64_t now, uint64_t* held_back = nullptr);

 private:
  int64_t interval_;
  int64_t last_ = kNoTime;
  uint64_t suppressed_ = 0;
};

}  // namespace stitch::sync
