// The pipe plumbing the benchmark's forked helper processes share (server_process.hpp,
// load_clients.hpp): whole reads and writes on a pipe, a read that gives up after a timeout,
// and the descriptor hygiene a child forked from the benchmark needs.
//
// Threading: plain functions on file descriptors; no state.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <cstddef>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::bench {

// Writes (reads) all `n` bytes, retrying on EINTR; false on an error or end of file.
bool write_all(int fd, const void* p, std::size_t n);
bool read_all(int fd, void* p, std::size_t n);

// Whether `fd` has something to read (or its end) within `timeout`.
bool wait_readable(int fd, std::chrono::milliseconds timeout);

// A child process and the parent's ends of its two pipes.
struct ForkedChild {
  pid_t pid = -1;
  int to_child = -1, from_child = -1;
};

// Forks a child that runs child_main(in, out) on its ends of the pipes; child_main must end
// with _exit. The child first closes every other inherited descriptor but stdio: the pipes of
// children forked earlier must reach EOF when the parent closes them. Call it while the
// process is one thread (a fork copies only the calling thread). io_error when fork or pipe
// fail.
Result<ForkedChild> fork_child(void (*child_main)(int in, int out));

// Closes the parent's ends (EOF: the child is expected to exit) and reaps the child, killing
// it if it has not exited after `grace`.
void end_child(ForkedChild& child, std::chrono::seconds grace);

}  // namespace deepcanvas::bench
