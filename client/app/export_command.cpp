// deepcanvas-client export: the canvas as a file, made by the server from the canvas as it stands
// (PROTOCOL.md 3.12), written here.
#include <cctype>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "cli_options.hpp"
#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/client_core/client.hpp"

namespace deepcanvas::client_app {

namespace {

namespace cli = deepcanvas::base::cli;

constexpr const char* kDescription =
    "Asks a running server for its canvas as a file and writes it: an OpenVDB volume (vdb: a\n"
    "density grid in 1/m and a Cd colour grid) or the paint's surface as a mesh with vertex\n"
    "colours (gltf, glb, ply), the same files as `deepcanvas-server export`. Joins as a viewer\n"
    "(a viewer's token will do). The file comes back in one message, so it must fit the\n"
    "server's max_frame_bytes (about 12 MB by default): choose a --voxel-size or a --box for\n"
    "more; the server says how large it would be.\n"
    "Exit status: 0 written, 1 refused or failed, 2 bad options.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client export --connect ws://127.0.0.1:7878/main --out main.glb\n"
    "  deepcanvas-client export --connect ws://127.0.0.1:7878/main --out main.vdb \\\n"
    "      --voxel-size 0.01 --box -1,0,-1,1,2,1\n";

int run_export(int argc, char** argv) {
  ConnectArgs connect;
  std::string out, format, box;
  double voxel_size = 0, timeout_s = 300;
  std::uint64_t max_bytes = 0;
  bool quiet = false;
  CLI::App app{kDescription, "deepcanvas-client export"};
  cli::standard(app, kExamples);
  add_connect_options(app, connect);
  app.add_option("--out", out, "the file to write (required)")
      ->type_name("FILE")
      ->check(output_file());
  app.add_option("--format", format, "vdb, gltf, glb or ply (default: from --out's extension)")
      ->type_name("FORMAT")
      ->check(CLI::IsMember({"vdb", "gltf", "glb", "ply"}));
  app.add_option("--voxel-size", voxel_size,
                 "voxel edge in metres, the nearest octree level (default: vdb the finest painted "
                 "cell; meshes the finest level within 1M triangles)")
      ->type_name("METRES")
      ->transform(positive());
  app.add_option("--box", box, "only the cells meeting this box (canvas metres)")
      ->type_name("X0,Y0,Z0,X1,Y1,Z1")
      ->check(box_corners());
  app.add_option("--max-bytes", max_bytes, "refuse a larger file (default: what one message holds)")
      ->type_name("N");
  app.add_option("--timeout", timeout_s, "how long to wait for the file (default 300)")
      ->type_name("SECONDS")
      ->transform(positive());
  app.add_flag("--quiet", quiet, "no progress on stderr");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  if (out.empty()) return usage_error(app, "--out FILE is required");
  if (format.empty()) format = file_format_of(out);
  if (format.empty())
    return usage_error(app, "--out " + out + ": give --format (vdb, gltf, glb, ply) or one of "
                              "those extensions");
  protocol::ExportRequest m;
  m.format = format;
  m.voxel_size_m = voxel_size;
  m.max_bytes = max_bytes;
  if (!box.empty()) m.box = *parse_box(box);  // checked by the option's box_corners() validator
  auto options = client_options(connect, protocol::Role::viewer, "deepcanvas-client export");
  options.keep_replica = false;
  options.block_frames = false;
  auto client = client_core::Client::connect(options);
  if (!client)
    return cli::fail(app, "cannot join canvas '" + options.canvas + "' at " + connect.url + ": " +
                              client.error().message);
  if (!quiet)
    std::fprintf(stderr, "export: asking for canvas '%s' as %s...\n", options.canvas.c_str(),
                 format.c_str());
  const auto t0 = std::chrono::steady_clock::now();
  auto id = (*client)->request_export(m);
  if (!id) return cli::fail(app, "export: " + id.error().message);
  auto r = (*client)->wait_for_export(
      *id, std::chrono::milliseconds(static_cast<std::int64_t>(timeout_s * 1000)));
  if (!r) return cli::fail(app, "the server refused the export: " + r.error().message);
  const std::string tmp = out + ".part";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    f.write(reinterpret_cast<const char*>(r->data.data()), static_cast<std::streamsize>(r->data.size()));
    f.close();
    if (!f) {
      std::error_code ec;
      std::filesystem::remove(tmp, ec);
      return cli::fail(app, "writing " + out + " failed (disk full?)");
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, out, ec);
  if (ec) return cli::fail(app, "writing " + out + ": " + ec.message());
  std::printf("wrote %s: canvas '%s' as %s, %zu bytes (%.2f s)\n", out.c_str(),
              options.canvas.c_str(), format.c_str(), r->data.size(),
              std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  (*client)->close();
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("export", "write a running server's canvas as vdb, gltf, glb or ply",
                          run_export);

}  // namespace deepcanvas::client_app
