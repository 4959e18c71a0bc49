// Imports converted in a separate process (`deepcanvas-server import-worker`), so that a file a
// client sends can never take the server down: OpenVDB's reader asserts and aborts on some
// damaged files, and no third-party reader is hardened against hostile bytes. The server runs
// this executable again (/proc/self/exe) for each import, with the file on stdin, under a memory
// limit and a deadline; the worker answers on stdout:
//   "OK\n" + the encoded cells (cell_paste.hpp)     the file converted
//   "ERR <errc name>\n" + the message                it did not (exit status 0 either way)
// Anything else (a crash, a kill, garbled output) is answered to the client as malformed.
#include "import_worker.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <cstdio>
#include <cstring>
#include <iterator>
#include <string>
#include <vector>

#include "cli_options.hpp"
#include "commands.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/export/mesh_export.hpp"
#include "deepcanvas/export/vdb_export.hpp"
#include "deepcanvas/export/volume_import.hpp"
#include "deepcanvas/protocol/messages.hpp"

namespace deepcanvas::server_app {

namespace {

namespace cli = deepcanvas::base::cli;

std::string number(double v) {
  char b[64];
  std::snprintf(b, sizeof b, "%.17g", v);
  return b;
}

// Writes all of `bytes` to `fd`; false on error.
bool write_all(int fd, const std::uint8_t* p, std::size_t n) {
  while (n > 0) {
    const ssize_t w = ::write(fd, p, n);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) return false;
    p += w;
    n -= static_cast<std::size_t>(w);
  }
  return true;
}

int worker_main(int argc, char** argv) {
  exporting::ImportOptions io;
  server_core::OctreeConfig canvas;
  std::string at, colour;
  CLI::App app{"Converts one import read from stdin into cells on stdout (used by serve; see "
               "import_worker.cpp).\n",
               "deepcanvas-server import-worker"};
  app.add_option("--format", io.format)->required();
  app.add_option("--at", at)->required();
  app.add_option("--scale", io.scale)->required();
  app.add_option("--voxel-size", io.voxel_size_m)->required();
  app.add_option("--colour", colour)->required();
  app.add_option("--density-scale", io.density_scale)->required();
  app.add_option("--roots", canvas.roots_per_axis)->required();
  app.add_option("--edge", canvas.edge_m)->required();
  app.add_option("--max-depth", canvas.max_depth)->required();
  if (auto code = cli::parse(app, argc, argv)) return *code;
  if (std::sscanf(at.c_str(), "%lf,%lf,%lf", &io.at[0], &io.at[1], &io.at[2]) != 3 ||
      std::sscanf(colour.c_str(), "%f,%f,%f", &io.colour[0], &io.colour[1], &io.colour[2]) != 3)
    return usage_error(app, "--at and --colour take three numbers");
  std::vector<std::uint8_t> file((std::istreambuf_iterator<char>(std::cin)), {});
  auto cells = exporting::import_cells(file, canvas, io);
  std::string head;
  std::vector<std::uint8_t> body;
  if (cells) {
    head = "OK\n";
    body = server_core::encode_cell_paste(*cells);
  } else {
    head = "ERR " + std::string(errc_name(cells.error().code)) + "\n";
    body.assign(cells.error().message.begin(), cells.error().message.end());
  }
  if (!write_all(1, reinterpret_cast<const std::uint8_t*>(head.data()), head.size()) ||
      !write_all(1, body.data(), body.size()))
    return 1;
  return 0;
}

}  // namespace

Result<server_core::CellPaste> import_in_worker(const protocol::Import& m,
                                                const server_core::OctreeConfig& canvas,
                                                const ImportWorkerLimits& limits) {
  // Everything the child needs is made before fork(): between fork() and exec() it only calls
  // async-signal-safe functions (this process has other threads).
  std::vector<std::string> args = {
      "/proc/self/exe", "import-worker", "--format", m.format,
      "--at", number(m.at[0]) + "," + number(m.at[1]) + "," + number(m.at[2]),
      "--scale", number(m.scale), "--voxel-size", number(m.voxel_size_m),
      "--colour", number(m.colour[0]) + "," + number(m.colour[1]) + "," + number(m.colour[2]),
      "--density-scale", number(m.density_scale), "--roots", std::to_string(canvas.roots_per_axis),
      "--edge", number(canvas.edge_m), "--max-depth", std::to_string(canvas.max_depth)};
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  int in[2], out[2];
  if (::pipe2(in, O_CLOEXEC) != 0) return make_error(Errc::io_error, "import: no pipe");
  if (::pipe2(out, O_CLOEXEC) != 0) {
    ::close(in[0]);
    ::close(in[1]);
    return make_error(Errc::io_error, "import: no pipe");
  }
  [[maybe_unused]] const rlimit mem{limits.memory_bytes, limits.memory_bytes};
  const pid_t pid = ::fork();
  if (pid < 0) {
    for (int fd : {in[0], in[1], out[0], out[1]}) ::close(fd);
    return make_error(Errc::io_error, "import: cannot start the import worker");
  }
  if (pid == 0) {
    ::dup2(in[0], 0);
    ::dup2(out[1], 1);
#if !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
    // (A sanitizer's runtime reserves terabytes of address space for its shadow memory: under
    // one, the worker runs without this limit.)
    ::setrlimit(RLIMIT_AS, &mem);
#endif
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  ::close(in[0]);
  ::close(out[1]);
  // The child reads all of stdin before it writes anything, so writing first cannot deadlock.
  ::signal(SIGPIPE, SIG_IGN);
  (void)write_all(in[1], m.data.data(), m.data.size());
  ::close(in[1]);
  std::vector<std::uint8_t> reply;
  const auto deadline = std::chrono::steady_clock::now() + limits.timeout;
  bool timed_out = false, too_big = false;
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) {
      timed_out = true;
      break;
    }
    pollfd p{out[0], POLLIN, 0};
    const int r = ::poll(&p, 1, static_cast<int>(std::min<std::int64_t>(left.count(), 1000)));
    if (r < 0 && errno == EINTR) continue;
    if (r == 0) continue;
    std::uint8_t buf[1 << 16];
    const ssize_t n = ::read(out[0], buf, sizeof buf);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    reply.insert(reply.end(), buf, buf + n);
    if (reply.size() > limits.max_reply_bytes) {
      too_big = true;
      break;
    }
  }
  ::close(out[0]);
  if (timed_out || too_big) ::kill(pid, SIGKILL);
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  if (timed_out)
    return make_error(Errc::limit_exceeded,
                      "the import took longer than " +
                          std::to_string(std::chrono::duration_cast<std::chrono::seconds>(limits.timeout).count()) +
                          " s to convert: choose a coarser --voxel-size or a smaller file");
  if (too_big) return make_error(Errc::limit_exceeded, "the import makes too many cells");
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
    return make_error(Errc::malformed,
                      "the " + m.format + " file could not be read (the reader " +
                          (WIFSIGNALED(status) ? "crashed with signal " + std::to_string(WTERMSIG(status))
                                               : "exited with status " + std::to_string(WEXITSTATUS(status))) +
                          "; a damaged file, or one past the import memory limit)");
  const std::string text(reply.begin(), reply.end());
  if (text.rfind("OK\n", 0) == 0)
    return server_core::decode_cell_paste(std::span(reply).subspan(3), canvas);
  if (text.rfind("ERR ", 0) == 0) {
    const auto nl = text.find('\n');
    if (nl != std::string::npos) {
      auto code = protocol::parse_errc(text.substr(4, nl - 4));
      return Error{code ? *code : Errc::malformed, text.substr(nl + 1)};
    }
  }
  return make_error(Errc::malformed, "the import worker answered nonsense");
}

Result<std::vector<std::uint8_t>> export_for_client(const server_core::Octree& tree,
                                                    const protocol::ExportRequest& request,
                                                    std::uint64_t max_bytes) {
  std::optional<server_core::Aabb> box;
  if (request.box) {
    const auto& b = *request.box;
    box = server_core::Aabb{{b[0], b[1], b[2]}, {b[3], b[4], b[5]}};
  }
  return exporting::export_to_bytes(tree, request.format, request.voxel_size_m, box, max_bytes);
}

DEEPCANVAS_SERVER_COMMAND("import-worker",
                          "internal: converts one import from stdin (serve runs it per import)",
                          worker_main);

}  // namespace deepcanvas::server_app
