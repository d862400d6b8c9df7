#pragma once

// What the sending and the receiving half of the udpm:// transport share (bus/udpm.h): LCM's
// wire format constants and the small helpers both use. Internal to bus/.

#include <chrono>
#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>

namespace stackgen::udpm_wire {

inline constexpr uint32_t kMagicShort = 0x4c433032;  // "LC02"
inline constexpr uint32_t kMagicLong = 0x4c433033;   // "LC03"
inline constexpr size_t kShortHeaderBytes = 8;
inline constexpr size_t kLongHeaderBytes = 20;
// LCM_MAX_CHANNEL_NAME_LENGTH
inline constexpr size_t kMaxChannelBytes = 63;

inline double SteadySeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

inline uint32_t GetU32(const uint8_t* in) {
  return (uint32_t{in[0]} << 24) | (uint32_t{in[1]} << 16) | (uint32_t{in[2]} << 8) | in[3];
}

inline void PutU32(uint8_t* out, uint32_t value) {
  out[0] = static_cast<uint8_t>(value >> 24);
  out[1] = static_cast<uint8_t>(value >> 16);
  out[2] = static_cast<uint8_t>(value >> 8);
  out[3] = static_cast<uint8_t>(value);
}

// "CALL: strerror(errno)"
inline std::string Errno(const std::string& call) {
  return call + ": " + std::strerror(errno);
}

}  // namespace stackgen::udpm_wire
