// Wall and CPU time of a CPU stage's phases on stderr, to see where a stage's time goes at a
// given thread count. Off unless STITCH_PROFILE (every stage) or STITCH_<STAGE>_PROFILE is set
// (STITCH_BLEND_PROFILE, STITCH_COLOR_PROFILE, STITCH_SEAMS_PROFILE); costs one test when off.
#pragma once

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <string>

namespace stitch {

class StageProfile {
 public:
  // `stage` names the output lines and the variable (upper-cased): "blend" -> STITCH_BLEND_PROFILE.
  // `enabled` comes from enabled_for(), kept in a function-local static by the caller.
  StageProfile(const char* stage, bool enabled) : stage_(stage), on_(enabled) {
    if (on_) last_cpu_ = cpu_ms();
  }
  static bool enabled_for(const char* stage) {
    if (std::getenv("STITCH_PROFILE")) return true;
    std::string name = "STITCH_";
    for (const char* c = stage; *c; ++c) name += char(*c >= 'a' && *c <= 'z' ? *c - 'a' + 'A' : *c);
    return std::getenv((name + "_PROFILE").c_str()) != nullptr;
  }
  // Prints the time since the last mark (or the start) as phase `what`.
  void mark(const char* what) {
    if (!on_) return;
    const auto now = std::chrono::steady_clock::now();
    const double cpu = cpu_ms();
    std::fprintf(stderr, "%s %s %.2f ms (CPU time %.2f ms)\n", stage_, what,
                 std::chrono::duration<double, std::milli>(now - last_).count(), cpu - last_cpu_);
    last_ = now;
    last_cpu_ = cpu;
  }

 private:
  static double cpu_ms() {  // the process' CPU time, all threads
    timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
  }
  const char* stage_;
  bool on_;
  std::chrono::steady_clock::time_point last_ = std::chrono::steady_clock::now();
  double last_cpu_ = 0;
};

}  // namespace stitch
