#include "bus/log.h"

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <csignal>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/process.h"

namespace stackgen {
namespace {

// the bytes of event `k` of writer `who`: its number, then a pattern, 1 byte to about 300 kB
std::vector<uint8_t> Payload(int who, int k) {
  std::vector<uint8_t> bytes(static_cast<size_t>(1 + (k * 7919 + who * 104729) % 300000));
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = static_cast<uint8_t>(i * 31 + k + who);
  bytes[0] = static_cast<uint8_t>(k);
  return bytes;
}

// two processes appending to one log at once: every event is read back whole, each writer's
// in the order it wrote them, as the DataLoader workers of one learner record their samples
TEST(LogAppenderTest, TwoProcessesAppendWholeEvents) {
  testing::ScratchDir dir;
  const std::string path = dir.path() + "/shared.lcmlog";
  constexpr int kEvents = 120;
  std::vector<pid_t> children;
  for (int who = 0; who < 2; ++who) {
    const pid_t pid = fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      LogAppender log(path);
      for (int k = 0; k < kEvents; ++k) {
        const std::vector<uint8_t> bytes = Payload(who, k);
        log.AppendBytes(who == 0 ? "WORKER_A" : "WORKER_B", bytes.data(), bytes.size(), k);
      }
      _exit(0);
    }
    children.push_back(pid);
  }
  for (const pid_t pid : children) {
    int status = 0;
    waitpid(pid, &status, 0);
    ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  }
  std::map<std::string, int> next = {{"WORKER_A", 0}, {"WORKER_B", 0}};
  const LogSummary summary = ReadLog(path, [&](const LogEvent& event) {
    ASSERT_EQ(next.count(event.channel), 1u) << event.channel;
    const int who = event.channel == "WORKER_A" ? 0 : 1;
    const int k = next[event.channel]++;
    const std::vector<uint8_t> expected = Payload(who, k);
    ASSERT_EQ(event.size, expected.size()) << event.channel << " " << k;
    EXPECT_TRUE(std::equal(expected.begin(), expected.end(), event.data)) << event.channel << k;
    EXPECT_EQ(event.utime, k);
  });
  EXPECT_EQ(summary.events, 2 * kEvents);
  EXPECT_EQ(summary.truncated_bytes, 0);
  EXPECT_EQ(next["WORKER_A"], kEvents);
  EXPECT_EQ(next["WORKER_B"], kEvents);
}

// a write that stops part way (here the file size limit, as a full disk would) leaves a torn
// last event; the appender then refuses every later event, so nothing follows the torn one and
// readers still read every whole event before it
TEST(LogAppenderTest, NothingFollowsATornEvent) {
  testing::ScratchDir dir;
  const std::string path = dir.path() + "/full.lcmlog";
  const std::vector<uint8_t> bytes(100, 7);
  const int64_t event_bytes = 28 + 8 + 100;  // header, channel, data
  const pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    signal(SIGXFSZ, SIG_IGN);
    const rlimit limit{static_cast<rlim_t>(2 * event_bytes + 40),
                       static_cast<rlim_t>(2 * event_bytes + 40)};
    if (setrlimit(RLIMIT_FSIZE, &limit) != 0) _exit(10);
    LogAppender log(path);
    log.AppendBytes("CHANNEL1", bytes.data(), bytes.size(), 0);
    log.AppendBytes("CHANNEL1", bytes.data(), bytes.size(), 1);
    int code = 11;
    try {
      log.AppendBytes("CHANNEL1", bytes.data(), bytes.size(), 2);  // 40 of its bytes fit
    } catch (const std::runtime_error& error) {
      code = std::string(error.what()).find("short write") != std::string::npos ? 0 : 12;
    }
    if (code != 0) _exit(code);
    const rlimit none{RLIM_INFINITY, RLIM_INFINITY};
    setrlimit(RLIMIT_FSIZE, &none);
    try {
      log.AppendBytes("CHANNEL1", bytes.data(), bytes.size(), 3);  // room again, still refused
      _exit(13);
    } catch (const std::runtime_error& error) {
      _exit(std::string(error.what()).find("cut short") != std::string::npos ? 0 : 14);
    }
  }
  int status = 0;
  waitpid(pid, &status, 0);
  ASSERT_TRUE(WIFEXITED(status)) << status;
  ASSERT_EQ(WEXITSTATUS(status), 0);
  int64_t events = 0;
  const LogSummary summary = ReadLog(path, [&](const LogEvent& event) {
    EXPECT_EQ(event.offset, events * event_bytes);
    ++events;
  });
  EXPECT_EQ(summary.events, 2);
  EXPECT_EQ(summary.truncated_bytes, 40);
}

// a folder or a file it may not write is one error naming it
TEST(LogAppenderTest, RefusesWhatItCannotOpen) {
  testing::ScratchDir dir;
  try {
    LogAppender log(dir.path());
    ADD_FAILURE() << "opened a folder";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find(dir.path()), std::string::npos) << error.what();
  }
}

}  // namespace
}  // namespace stackgen
