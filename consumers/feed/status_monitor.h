#pragma once

#include <map>
#include <memory>
#include <string>

#include <stackgen/status.hpp>

namespace stackgen::feed {

/// Listens to STACKGEN_STATUS in a thread of its own and keeps the latest status of every process
/// (by status.name), so a training loop can show how fast the generators produce. A best-effort
/// listener: it sends nothing but the liveness check of the bus key. Messages that do not decode
/// or are refused by the key are skipped.
class StatusMonitor {
 public:
  /// Opens the bus at `url` (empty: ResolveLcmUrl("")) with the bus key `key_file` (empty:
  /// ResolveBusKeyFile's choice), or none when `open_bus`; throws FeedError naming the URL or
  /// key file if it cannot.
  StatusMonitor(const std::string& url, const std::string& key_file, bool open_bus);
  /// Stops the thread (a copy inherited by a forked process, which has no thread, is left).
  ~StatusMonitor();
  StatusMonitor(const StatusMonitor&) = delete;
  StatusMonitor& operator=(const StatusMonitor&) = delete;

  /// The latest status of each process heard, by name (at most 1024: past that, the process
  /// heard from least recently is dropped).
  std::map<std::string, status> Latest() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen::feed
