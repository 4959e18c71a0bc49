// A canvas written to bytes (declared in mesh_export.hpp): what a running
// server sends a client that asks for its canvas (PROTOCOL.md 3.12).
#include <atomic>
#include <filesystem>
#include <fstream>
#include <unistd.h>

#include "deepcanvas/export/mesh_export.hpp"
#include "deepcanvas/export/vdb_export.hpp"

namespace deepcanvas::exporting {

Result<std::vector<std::uint8_t>> export_to_bytes(const server_core::Octree& tree,
                                                  const std::string& format, double voxel_size_m,
                                                  const std::optional<server_core::Aabb>& box,
                                                  std::uint64_t max_bytes) {
  VdbExportOptions xo;
  if (voxel_size_m > 0) xo.voxel_depth = voxel_depth_for(tree.config(), voxel_size_m);
  xo.box = box;
  auto too_large = [&](std::uint64_t estimate) {
    return make_error(Errc::limit_exceeded,
                      "the " + format + " file would take about " + std::to_string(estimate) +
                          " bytes, more than " + std::to_string(max_bytes) +
                          " (one message, or max_bytes): choose a coarser voxel size or a box");
  };
  static std::atomic<std::uint64_t> serial{0};
  const std::filesystem::path tmp =
      std::filesystem::temp_directory_path() /
      ("deepcanvas-export-" + std::to_string(::getpid()) + "-" + std::to_string(++serial) + "." +
       format);
  if (format != "vdb" && format != "gltf" && format != "glb" && format != "ply")
    return make_error(Errc::invalid_argument, "format " + format + ": not vdb, gltf, glb or ply");
  if (format == "vdb") {
    auto est = estimate_vdb(tree, xo);
    if (!est) return std::move(est).error();
    if (est->estimated_bytes > max_bytes) return too_large(est->estimated_bytes);
    xo.max_bytes = max_bytes;
    auto w = export_vdb(tree, xo, tmp.string());
    if (!w) return std::move(w).error();
  } else {
    MeshExportOptions mo;
    mo.volume = xo;
    auto mesh = mesh_canvas(tree, mo);
    if (!mesh) return std::move(mesh).error();
    const auto mf = format == "ply"   ? MeshFormat::ply
                    : format == "glb" ? MeshFormat::glb
                                      : MeshFormat::gltf;
    const std::uint64_t est = estimate_mesh_bytes(*mesh, mf);
    if (est > max_bytes) return too_large(est);
    auto w = write_mesh(*mesh, mf, tmp.string());
    if (!w) return std::move(w).error();
  }
  std::ifstream in(tmp, std::ios::binary);
  std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)), {});
  std::error_code ec;
  std::filesystem::remove(tmp, ec);
  if (bytes.size() > max_bytes) return too_large(bytes.size());
  if (bytes.empty()) return make_error(Errc::io_error, "the export file could not be read back");
  return bytes;
}

}  // namespace deepcanvas::exporting
