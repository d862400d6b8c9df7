#include "consumers/feed/status_monitor.h"

#include <unistd.h>

#include <atomic>
#include <mutex>
#include <thread>

#include "bus/bus.h"
#include "bus/channels.h"
#include "consumers/feed/scene_data.h"

namespace stackgen::feed {
namespace {

// the most processes whose latest status is kept
constexpr size_t kMaxProcesses = 1024;

}  // namespace

struct StatusMonitor::Impl {
  std::unique_ptr<Bus> bus;
  mutable std::mutex mutex;
  std::map<std::string, status> latest;
  std::map<std::string, int64_t> heard;  // when each was last heard (counting messages)
  int64_t messages = 0;
  std::atomic<bool> stop{false};
  std::thread thread;
  pid_t pid = 0;
};

StatusMonitor::StatusMonitor(const std::string& url, const std::string& key_file, bool open_bus)
    : impl_(std::make_unique<Impl>()) {
  Impl* impl = impl_.get();
  impl->pid = getpid();
  impl->bus = OpenBus(url, key_file, open_bus);
  impl->bus->Subscribe<status>(
      kStatusChannel,
      [impl](const status& message) {
        const std::lock_guard<std::mutex> lock(impl->mutex);
        // names a stranger could vary without end are bounded: the oldest news goes first
        if (impl->latest.size() >= kMaxProcesses && impl->latest.count(message.name) == 0) {
          auto oldest = impl->heard.begin();
          for (auto it = impl->heard.begin(); it != impl->heard.end(); ++it) {
            if (it->second < oldest->second) oldest = it;
          }
          impl->latest.erase(oldest->first);
          impl->heard.erase(oldest);
        }
        impl->latest[message.name] = message;
        impl->heard[message.name] = ++impl->messages;
      },
      256, [](const std::string&) {});
  impl->thread = std::thread([impl] {
    try {
      while (!impl->stop) impl->bus->HandleFor(50);
    } catch (const std::exception&) {
      // a failing bus only ends the monitoring
    }
  });
}

StatusMonitor::~StatusMonitor() {
  if (impl_->pid != getpid()) {
    impl_.release();
    return;
  }
  impl_->stop = true;
  if (impl_->thread.joinable()) impl_->thread.join();
}

std::map<std::string, status> StatusMonitor::Latest() const {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->latest;
}

}  // namespace stackgen::feed
