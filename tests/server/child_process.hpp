// A deepcanvas-server child process for the tests that run the server as an operator does
// (signals, kill -9, restarts): $DEEPCANVAS_SERVER + args, its stderr (and optionally stdout)
// collected for wait_for() and output().
#pragma once

#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <cstdlib>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace deepcanvas::test {

// `command` run as a child process ($DEEPCANVAS_SERVER + args, or the program named by another
// variable, or with `program_env` empty args[0] looked up on PATH); its stderr is collected.
// `nofile`: non-zero sets the child's RLIMIT_NOFILE.
class Child {
 public:
  explicit Child(std::vector<std::string> args, bool stdout_too = false,
                 const std::string& program_env = "DEEPCANVAS_SERVER", rlim_t nofile = 0) {
    if (!program_env.empty()) {
      const char* path = std::getenv(program_env.c_str());
      if (!path) {
        ADD_FAILURE() << program_env << " is not set";
        return;
      }
      args.insert(args.begin(), path);
    }
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    int fds[2];
    if (pipe2(fds, O_CLOEXEC) != 0) return;
    pid_ = fork();
    if (pid_ == 0) {  // only async-signal-safe calls until exec
      dup2(fds[1], 2);
      if (stdout_too) dup2(fds[1], 1);
      if (nofile) {
        rlimit r{nofile, nofile};
        setrlimit(RLIMIT_NOFILE, &r);
      }
      execvp(argv[0], argv.data());
      _exit(127);
    }
    close(fds[1]);
    reader_ = std::thread([this, fd = fds[0]] {
      char buf[4096];
      for (;;) {
        const ssize_t n = read(fd, buf, sizeof buf);
        if (n <= 0) break;
        std::lock_guard lock(mutex_);
        out_.append(buf, static_cast<std::size_t>(n));
        cv_.notify_all();
      }
      close(fd);
      std::lock_guard lock(mutex_);
      ended_ = true;
      cv_.notify_all();
    });
  }
  ~Child() {
    if (pid_ > 0 && !exited_) {
      kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
    }
    if (reader_.joinable()) reader_.join();
  }
  // Until the output holds `needle` `count` times (false on timeout or when the output ends
  // first).
  bool wait_for(const std::string& needle, std::chrono::milliseconds timeout,
                std::size_t count = 1) {
    const auto seen = [&] {
      std::size_t n = 0;
      for (auto at = out_.find(needle); at != std::string::npos; at = out_.find(needle, at + 1))
        ++n;
      return n >= count;
    };
    std::unique_lock lock(mutex_);
    return cv_.wait_for(lock, timeout, [&] { return seen() || ended_; }) && seen();
  }
  std::string output() const {
    std::lock_guard lock(mutex_);
    return out_;
  }
  void signal(int sig) { kill(pid_, sig); }
  pid_t pid() const { return pid_; }
  bool alive() const { return pid_ > 0 && !exited_ && kill(pid_, 0) == 0; }
  // The exit status once the child has exited and its output is all read (-1 on timeout).
  int wait_exit(std::chrono::milliseconds timeout) {
    {
      std::unique_lock lock(mutex_);
      if (!cv_.wait_for(lock, timeout, [&] { return ended_; })) return -1;
    }
    int status = 0;
    if (waitpid(pid_, &status, 0) != pid_) return -1;
    exited_ = true;
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  }

 private:
  pid_t pid_ = -1;
  bool exited_ = false;
  bool ended_ = false;
  std::thread reader_;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::string out_;
};

// The port of the server whose output holds its "event=listening" line (0 when there is none).
inline int listening_port(const std::string& output, std::size_t from = 0) {
  const auto line = output.find("event=listening", from);
  if (line == std::string::npos) return 0;
  const auto at = output.find("port=", line);
  return at == std::string::npos ? 0 : std::atoi(output.c_str() + at + 5);
}

}  // namespace deepcanvas::test
