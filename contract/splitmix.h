#pragma once

// SplitMix64 (Steele, Lea, Flood 2014), in one place for the generator's seed derivation and
// sensor noise and the bus's fault injection: a fast 64-bit generator whose output function is
// also a strong 64-bit hash. Header only; changing it changes every scene
// (docs/design.md, "Determinism").

#include <cstdint>

namespace stackgen {

/// The golden-ratio increment of the SplitMix64 state.
inline constexpr uint64_t kSplitMixGamma = 0x9e3779b97f4a7c15ULL;

/// SplitMix64's output function: a strong 64-bit mix of `z`.
inline constexpr uint64_t Mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

/// One SplitMix64 step from state `x`, as a hash: Mix64(x + kSplitMixGamma). Seeds derived with
/// it (scene seeds, per-lever engines) are pure functions of their inputs.
inline constexpr uint64_t SplitMixHash(uint64_t x) { return Mix64(x + kSplitMixGamma); }

/// The SplitMix64 engine: 64 bits per call, statistically sound for noise and fault injection.
class SplitMix64 {
 public:
  explicit SplitMix64(uint64_t seed) : state_(seed) {}
  uint64_t Next() { return Mix64(state_ += kSplitMixGamma); }

 private:
  uint64_t state_;
};

}  // namespace stackgen
