#include "tiled_canvas.hpp"

#include <cstdio>
#include <fstream>

namespace deepcanvas::bench {

Result<nlohmann::json> generate_tiled_log(const std::string& server,
                                          const std::filesystem::path& paintings, std::uint64_t n,
                                          const std::string& log) {
  const std::string cmd = "'" + server + "' replay --tile-to-cells " + std::to_string(n) +
                          " --seed 7 '" + (paintings / "demo.apa").string() + "' '" +
                          (paintings / "dancer.apa").string() + "' --log-out '" + log +
                          "' --json --quiet";
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return make_error(Errc::io_error, "cannot run " + server + " replay");
  std::string out;
  char buf[4096];
  while (std::size_t k = std::fread(buf, 1, sizeof buf, p)) out.append(buf, k);
  if (::pclose(p) != 0) return make_error(Errc::io_error, "replay --tile-to-cells failed");
  auto j = nlohmann::json::parse(out, nullptr, false);
  if (j.is_discarded()) return make_error(Errc::malformed, "replay --tile-to-cells: no JSON");
  return j;
}

std::uint64_t rss_bytes(pid_t pid) {
  std::ifstream in(pid == 0 ? std::string("/proc/self/status")
                            : "/proc/" + std::to_string(pid) + "/status");
  for (std::string line; std::getline(in, line);)
    if (line.rfind("VmRSS:", 0) == 0) return std::stoull(line.substr(6)) * 1024;
  return 0;
}

}  // namespace deepcanvas::bench
