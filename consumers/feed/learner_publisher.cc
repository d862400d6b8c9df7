#include "consumers/feed/learner_publisher.h"

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <mutex>
#include <thread>

#include <stackgen/learner_status.hpp>

#include "bus/auth.h"
#include "bus/bus.h"
#include "bus/channels.h"
#include "bus/clock.h"
#include "consumers/feed/scene_data.h"

namespace stackgen::feed {

struct LearnerPublisher::Impl {
  std::unique_ptr<Bus> bus;
  std::string process, name;
  std::mutex mutex;
  LearnerReport latest;
  bool fresh = false;
  std::atomic<bool> stop{false};
  std::thread thread;
  bool closed = false;
  pid_t pid = 0;

  // the message of `report` with `run_state`, stamped now
  learner_status Message(const LearnerReport& report, int8_t run_state) const {
    learner_status out{};
    out.header.seq = -1;
    out.header.generator_id = -1;
    out.header.utime = UnixMicros();
    out.process = process;
    out.name = name;
    out.steps = report.steps;
    out.target_steps = report.target_steps;
    out.loss = report.loss;
    out.scenes_taken = report.scenes_taken;
    out.scenes_per_second = report.scenes_per_second;
    out.reuse = report.reuse;
    out.run_state = run_state;
    return out;
  }
};

LearnerPublisher::LearnerPublisher(const std::string& url, const std::string& key_file,
                                   bool open_bus, const std::string& process,
                                   const std::string& name)
    : impl_(std::make_unique<Impl>()) {
  Impl* impl = impl_.get();
  impl->pid = getpid();
  impl->process = process;
  impl->name = name;
  impl->bus = OpenBus(url, key_file, open_bus);
  impl->thread = std::thread([impl] {
    const Clock& clock = SteadyClock();
    auto last = clock.Now();
    try {
      while (!impl->stop) {
        impl->bus->HandleFor(50);
        if (clock.Now() - last < std::chrono::seconds(1)) continue;
        last = clock.Now();
        LearnerReport report;
        {
          const std::lock_guard<std::mutex> lock(impl->mutex);
          if (!impl->fresh) continue;
          report = impl->latest;
        }
        impl->bus->Publish(kLearnerChannel, impl->Message(report, 0));
      }
    } catch (const std::exception&) {
      // a failing bus only ends the reports
    }
  });
}

LearnerPublisher::~LearnerPublisher() {
  if (impl_->pid != getpid()) {
    // a copy inherited by a forked process (a DataLoader worker) has no thread
    impl_.release();
    return;
  }
  Close(false);
}

void LearnerPublisher::Report(const LearnerReport& report) {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->latest = report;
  impl_->fresh = true;
}

void LearnerPublisher::Close(bool ended) {
  if (impl_->closed) return;
  impl_->closed = true;
  impl_->stop = true;
  if (impl_->thread.joinable()) impl_->thread.join();
  LearnerReport report;
  {
    const std::lock_guard<std::mutex> lock(impl_->mutex);
    report = impl_->latest;
  }
  try {
    for (int k = 0; k < 3; ++k) {
      impl_->bus->Publish(kLearnerChannel, impl_->Message(report, ended ? 1 : 2));
    }
  } catch (const std::exception&) {
    // the last word is best effort
  }
}

}  // namespace stackgen::feed
