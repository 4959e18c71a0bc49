// deepcanvas-client import: sends a volume or mesh file to a server, which pastes it into the
// canvas as one operation (PROTOCOL.md 3.11).
#include <cctype>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "cli_options.hpp"
#include "commands.hpp"
#include "connect_options.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "resumable_paint.hpp"

namespace deepcanvas::client_app {

namespace {

namespace cli = deepcanvas::base::cli;

constexpr const char* kDescription =
    "Sends FILE (an OpenVDB volume, or a glTF, glb or PLY mesh) to a deepcanvas server as a\n"
    "painter; the server converts it into cells and pastes it into the canvas as one operation,\n"
    "streamed to every client and taken back by this painter's undo (same --client-id). A fog\n"
    "volume's values are extinction per file unit (Blender and Houdini density); a level set\n"
    "or a closed mesh becomes a solid. The file travels in one message, so it must fit the\n"
    "server's max_frame_bytes (about 12 MB by default).\n"
    "Exit status: 0 pasted, 1 refused (the server's reason is printed), 2 bad options.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client import smoke.vdb --connect ws://127.0.0.1:7878/main --at 0,1,0\n"
    "  deepcanvas-client import bunny.ply --scale 0.01 --voxel-size 0.005 --colour 0.8,0.6,0.5\n"
    "      a mesh in centimetres, as 5 mm cells, grey-brown where it has no vertex colours\n"
    "  deepcanvas-client import part.glb --client-id alice; then\n"
    "  deepcanvas-client paint --client-id alice --undo-last 1   takes the import back\n";

Result<std::vector<std::uint8_t>> read_file(const std::string& path, std::uint64_t limit) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))
    return make_error(Errc::not_found, "no file " + path);
  const auto size = std::filesystem::file_size(path, ec);
  if (ec) return make_error(Errc::io_error, path + ": " + ec.message());
  if (size == 0) return make_error(Errc::invalid_argument, path + " is empty");
  if (size > limit)
    return make_error(Errc::limit_exceeded,
                      path + " is " + std::to_string(size) + " bytes; one import message holds at " +
                          "most " + std::to_string(limit) + " (the server's max_frame_bytes)");
  std::ifstream in(path, std::ios::binary);
  std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)), {});
  if (bytes.size() != size) return make_error(Errc::io_error, "reading " + path + " failed");
  return bytes;
}

int run_import(int argc, char** argv) {
  ConnectArgs connect;
  std::string file, format, at, colour, client_id;
  double scale = 1, voxel_size = 0, density_scale = 1, timeout_s = 300;
  bool quiet = false;

  CLI::App app{kDescription, "deepcanvas-client import"};
  cli::standard(app, kExamples);
  add_connect_options(app, connect);
  app.add_option("FILE", file, "the file to import (.vdb, .gltf, .glb, .ply)")
      ->type_name("FILE")
      ->required();
  app.add_option("--format", format, "vdb, gltf, glb or ply (default: from FILE's extension)")
      ->type_name("FORMAT")
      ->check(CLI::IsMember({"vdb", "gltf", "glb", "ply"}));
  app.add_option("--at", at, "where the file's origin goes, canvas metres (default 0,0,0)")
      ->type_name("X,Y,Z")
      ->check(triple());
  app.add_option("--scale", scale, "metres per file unit (default 1)")
      ->type_name("S")
      ->transform(positive());
  app.add_option("--voxel-size", voxel_size,
                 "cell edge to import at, metres, rounded to the nearest octree level (default: "
                 "the file's own voxels; meshes: 1/128 of their size)")
      ->type_name("METRES")
      ->transform(positive());
  app.add_option("--colour", colour, "colour where the file has none, 0..1 (default 1,1,1)")
      ->type_name("R,G,B")
      ->check(triple());
  app.add_option("--density-scale", density_scale,
                 "fog volumes: extinction per metre = value x this / scale (default 1)")
      ->type_name("K")
      ->transform(positive());
  app.add_option("--client-id", client_id,
                 "the painter's id: `paint --client-id ID --undo-last 1` then takes the import back "
                 "(default: a random id)")
      ->type_name("ID")
      ->check(CLI::Validator(
          [](std::string& v) -> std::string {
            return protocol::is_valid_client_id(v) ? std::string()
                                                   : "1 to 64 characters of A-Z a-z 0-9 _ -";
          },
          ""));
  app.add_option("--timeout", timeout_s, "how long to wait for the answer (default 300)")
      ->type_name("SECONDS")
      ->transform(positive());
  app.add_flag("--quiet", quiet, "no progress on stderr");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;

  protocol::Import m;
  if (format.empty()) format = file_format_of(file);
  if (format.empty())
    return usage_error(app, file + ": give --format (vdb, gltf, glb, ply) or one of "
                                     "those extensions");
  m.format = format;
  if (!at.empty()) m.at = *parse_triple(at);
  if (!colour.empty()) {
    const auto c = *parse_triple(colour);
    for (int i = 0; i < 3; ++i) {
      if (!(c[static_cast<std::size_t>(i)] >= 0 && c[static_cast<std::size_t>(i)] <= 1))
        return usage_error(app, "--colour: each value lies in 0..1");
      m.colour[static_cast<std::size_t>(i)] = static_cast<float>(c[static_cast<std::size_t>(i)]);
    }
  }
  m.scale = scale;
  m.voxel_size_m = voxel_size;
  m.density_scale = density_scale;

  auto options = client_options(connect, protocol::Role::painter, "deepcanvas-client import");
  options.keep_replica = false;
  options.block_frames = false;
  options.client_id = client_id.empty() ? random_client_id() : client_id;
  auto client = client_core::Client::connect(options);
  if (!client)
    return cli::fail(app, "cannot join canvas '" + options.canvas + "' at " + connect.url + ": " +
                              client.error().message);
  // base64 makes 4 characters of 3 bytes; the rest of the message is a few hundred bytes.
  const std::uint64_t limit = ((*client)->welcome().limits.max_frame_bytes - 1024) / 4 * 3;
  auto bytes = read_file(file, limit);
  if (!bytes) return cli::fail(app, bytes.error().message);
  m.data = std::move(*bytes);
  const std::size_t size = m.data.size();
  if (!quiet)
    std::fprintf(stderr, "import: sending %s (%zu bytes) to canvas '%s'...\n", file.c_str(), size,
                 options.canvas.c_str());
  const auto t0 = std::chrono::steady_clock::now();
  auto id = (*client)->request_import(std::move(m));
  if (!id) return cli::fail(app, "import: " + id.error().message);
  auto r = (*client)->wait_for_import(
      *id, std::chrono::milliseconds(static_cast<std::int64_t>(timeout_s * 1000)));
  if (!r) return cli::fail(app, "the server refused the import: " + r.error().message);
  const double secs =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("imported %s into canvas '%s': %llu cells as operation %llu in epoch %llu (%.2f s)\n",
              file.c_str(), options.canvas.c_str(), static_cast<unsigned long long>(r->cells),
              static_cast<unsigned long long>(r->stroke_id),
              static_cast<unsigned long long>(r->epoch), secs);
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("import", "paste a volume (.vdb) or mesh (.gltf .glb .ply) into a canvas",
                          run_import);

}  // namespace deepcanvas::client_app
