#pragma once

// Test helpers: start programs as real processes, pick free ports, make temp folders.

#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <system_error>
#include <thread>
#include <vector>

namespace stackgen::testing {

/// config/default.pbtxt's parts, bin and a fixed camera, without its drawn look, with the landed
/// rule as the settle rule (1 mm, 1 degree over 0.25 s), for end-to-end tests that depend on
/// neither: about 0.6 times the physics.
inline const std::string kLandedRule =
    std::string(STACKGEN_SOURCE_DIR) + "/tests/fixtures/scene/landed_rule.pbtxt";

/// A UDP port nothing on this host is bound to right now.
inline int FreeUdpPort() {
  const int fd = socket(AF_INET, SOCK_DGRAM, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_ANY);
  bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof(address));
  socklen_t length = sizeof(address);
  getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length);
  close(fd);
  return ntohs(address.sin_port);
}

/// The path of program `name` found on $PATH; empty if it is not there.
inline std::string FindOnPath(const std::string& name) {
  const char* path = std::getenv("PATH");
  const std::string folders = path != nullptr ? path : "/usr/bin:/bin";
  size_t start = 0;
  while (start <= folders.size()) {
    const size_t end = std::min(folders.find(':', start), folders.size());
    const std::filesystem::path candidate =
        std::filesystem::path(folders.substr(start, end - start)) / name;
    if (access(candidate.c_str(), X_OK) == 0) return candidate.string();
    start = end + 1;
  }
  return "";
}

/// A multicast URL on this host only, on a free port.
inline std::string FreeMulticastUrl() {
  return "udpm://239.255.76.67:" + std::to_string(FreeUdpPort()) + "?ttl=0&recv_buf_size=4194304";
}

/// A new empty folder under $TMPDIR (or /tmp).
inline std::string MakeTempDir(const std::string& prefix) {
  // every folder made here is removed, with what it holds, when the test program exits: a
  // suite leaves nothing in /tmp (a folder a test needs gone sooner is a ScratchDir)
  struct Made {
    std::mutex mutex;
    std::vector<std::string> paths;
    ~Made() {
      // a forked child that did not exec leaves the parent's folders alone
      if (getpid() != owner) return;
      std::error_code error;
      for (const std::string& path : paths) std::filesystem::remove_all(path, error);
    }
    pid_t owner = getpid();
  };
  static Made made;
  const char* tmp = std::getenv("TMPDIR");
  std::string pattern = std::string(tmp != nullptr ? tmp : "/tmp") + "/" + prefix + ".XXXXXX";
  if (mkdtemp(pattern.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
  const std::lock_guard<std::mutex> lock(made.mutex);
  made.paths.push_back(pattern);
  return pattern;
}

/// A fresh temp folder (see MakeTempDir), removed with everything in it when destroyed.
class ScratchDir {
 public:
  explicit ScratchDir(const std::string& prefix = "stackgen-test") : path_(MakeTempDir(prefix)) {}
  ~ScratchDir() {
    std::error_code error;
    std::filesystem::remove_all(path_, error);
  }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

inline std::string ReadFile(const std::string& path) {
  std::ifstream file(path);
  std::ostringstream text;
  text << file.rdbuf();
  return text.str();
}

/// Sets (or, with nullptr, unsets) an environment variable for the processes started while it
/// lives, and restores it after. E.g. ScopedEnv("STACKGEN_BUS_KEY_FILE", nullptr) for a log
/// recorded without a bus key.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const char* value) : name_(name) {
    const char* old = std::getenv(name);
    had_ = old != nullptr;
    if (had_) old_ = old;
    if (value != nullptr) {
      setenv(name, value, 1);
    } else {
      unsetenv(name);
    }
  }
  ~ScopedEnv() {
    if (had_) {
      setenv(name_.c_str(), old_.c_str(), 1);
    } else {
      unsetenv(name_.c_str());
    }
  }
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;

 private:
  std::string name_;
  std::string old_;
  bool had_ = false;
};

/// A child process whose stdout and stderr go to files.
class Process {
 public:
  /// Starts `argv[0]` with arguments; output to `log_prefix`.out and .err.
  Process(const std::vector<std::string>& argv, const std::string& log_prefix)
      : out_path_(log_prefix + ".out"), err_path_(log_prefix + ".err") {
    pid_ = fork();
    if (pid_ < 0) throw std::runtime_error("fork failed");
    if (pid_ == 0) {
      const int out = open(out_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      const int err = open(err_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      dup2(out, STDOUT_FILENO);
      dup2(err, STDERR_FILENO);
      std::vector<char*> args;
      for (const std::string& arg : argv) args.push_back(const_cast<char*>(arg.c_str()));
      args.push_back(nullptr);
      execv(args[0], args.data());
      _exit(127);
    }
  }
  ~Process() {
    if (pid_ > 0 && !exited_) {
      kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
    }
  }
  Process(const Process&) = delete;
  Process& operator=(const Process&) = delete;

  /// Waits up to `timeout_s` for the process to exit; returns its exit code, or -1 if it is
  /// still running (it is then sent SIGKILL).
  int Wait(double timeout_s) {
    const auto deadline =
        std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    while (std::chrono::steady_clock::now() < deadline) {
      if (Exited()) return code_;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    kill(pid_, SIGKILL);
    waitpid(pid_, nullptr, 0);
    exited_ = true;
    return -1;
  }

  /// Waits up to `timeout_s` until stdout contains `text`; false if it did not appear.
  bool WaitForOutput(const std::string& text, double timeout_s) const {
    const auto deadline =
        std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    while (std::chrono::steady_clock::now() < deadline) {
      if (ReadFile(out_path_).find(text) != std::string::npos) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
  }

  /// Waits up to `timeout_s` until stderr contains `text`; false if it did not appear.
  bool WaitForError(const std::string& text, double timeout_s) const {
    const auto deadline =
        std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    while (std::chrono::steady_clock::now() < deadline) {
      if (Stderr().find(text) != std::string::npos) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
  }

  /// True once the process has exited (without waiting); Wait then returns its exit code.
  bool Exited() {
    if (exited_) return true;
    int status = 0;
    if (waitpid(pid_, &status, WNOHANG) != pid_) return false;
    exited_ = true;
    code_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    return true;
  }

  pid_t pid() const { return pid_; }
  void Signal(int signal_number) const { kill(pid_, signal_number); }
  std::string Stdout() const { return ReadFile(out_path_); }
  std::string Stderr() const { return ReadFile(err_path_); }

 private:
  std::string out_path_;
  std::string err_path_;
  pid_t pid_ = -1;
  bool exited_ = false;
  int code_ = -1;
};

/// Runs `program` with `args` to the end (at most `timeout_s`, then SIGKILL and -1), output to
/// `log_prefix`.out and .err; returns its exit code and hands back what it printed.
inline int RunToEnd(const std::string& program, const std::vector<std::string>& args,
                    const std::string& log_prefix, std::string* out, std::string* err,
                    double timeout_s) {
  std::vector<std::string> argv = {program};
  argv.insert(argv.end(), args.begin(), args.end());
  Process process(argv, log_prefix);
  const int code = process.Wait(timeout_s);
  *out = process.Stdout();
  *err = process.Stderr();
  return code;
}

}  // namespace stackgen::testing
