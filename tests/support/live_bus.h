#pragma once

// For tests that publish from a Bus of their own to a running stackgen process: with a bus key,
// that process takes a sender's messages only once the sender has answered its liveness check
// (bus/liveness.h), so a Bus that publishes at once would see its first messages dropped.

#include <chrono>

#include "bus/bus.h"

namespace stackgen::testing {

/// Waits until another process on `bus` has answered its liveness check (that process then
/// challenged it back, and the bus's own thread answered), then 50 ms more for that answer to
/// arrive. False after `timeout_s` without one.
inline bool WaitForLivePeer(Bus& bus, double timeout_s) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (bus.state().live_peers() == 0) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    bus.HandleFor(20);
  }
  bus.HandleFor(50);
  return true;
}

}  // namespace stackgen::testing
