// See child_pipe.hpp.
#include "child_pipe.hpp"

#include <dirent.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

namespace deepcanvas::bench {

bool write_all(int fd, const void* p, std::size_t n) {
  const auto* b = static_cast<const char*>(p);
  while (n > 0) {
    const ssize_t w = ::write(fd, b, n);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) return false;
    b += w;
    n -= static_cast<std::size_t>(w);
  }
  return true;
}

bool read_all(int fd, void* p, std::size_t n) {
  auto* b = static_cast<char*>(p);
  while (n > 0) {
    const ssize_t r = ::read(fd, b, n);
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) return false;
    b += r;
    n -= static_cast<std::size_t>(r);
  }
  return true;
}

bool wait_readable(int fd, std::chrono::milliseconds timeout) {
  pollfd p{fd, POLLIN, 0};
  int n = 0;
  do n = poll(&p, 1, static_cast<int>(timeout.count()));
  while (n < 0 && errno == EINTR);
  return n > 0;
}

namespace {

void close_other_fds(int keep_a, int keep_b) {
  std::vector<int> fds;
  if (DIR* d = opendir("/proc/self/fd")) {
    while (dirent* e = readdir(d)) {
      const int fd = std::atoi(e->d_name);
      if (fd > 2 && fd != keep_a && fd != keep_b && fd != dirfd(d)) fds.push_back(fd);
    }
    closedir(d);
  }
  for (int fd : fds) ::close(fd);
}

}  // namespace

Result<ForkedChild> fork_child(void (*child_main)(int in, int out)) {
  int down[2], up[2];
  if (pipe(down) != 0) return make_error(Errc::io_error, std::string("pipe: ") + strerror(errno));
  if (pipe(up) != 0) {
    ::close(down[0]);
    ::close(down[1]);
    return make_error(Errc::io_error, std::string("pipe: ") + strerror(errno));
  }
  std::fflush(nullptr);
  const pid_t pid = fork();
  if (pid < 0) {
    for (int fd : {down[0], down[1], up[0], up[1]}) ::close(fd);
    return make_error(Errc::io_error, std::string("fork: ") + strerror(errno));
  }
  if (pid == 0) {
    close_other_fds(down[0], up[1]);
    child_main(down[0], up[1]);
    _exit(0);
  }
  ::close(down[0]);
  ::close(up[1]);
  return ForkedChild{pid, down[1], up[0]};
}

void end_child(ForkedChild& child, std::chrono::seconds grace) {
  for (int* fd : {&child.to_child, &child.from_child})
    if (*fd >= 0) {
      ::close(*fd);
      *fd = -1;
    }
  if (child.pid <= 0) return;
  const auto deadline = std::chrono::steady_clock::now() + grace;
  int status = 0;
  while (waitpid(child.pid, &status, WNOHANG) == 0) {
    if (std::chrono::steady_clock::now() > deadline) {
      kill(child.pid, SIGKILL);
      waitpid(child.pid, &status, 0);
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  child.pid = -1;
}

}  // namespace deepcanvas::bench
