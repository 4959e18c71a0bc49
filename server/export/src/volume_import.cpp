#include "deepcanvas/export/volume_import.hpp"

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/MeshToVolume.h>

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <unordered_map>
#include <unordered_set>
#include <utility>

#include "deepcanvas/export/mesh_export.hpp"
#include "deepcanvas/protocol/density_model.hpp"
#include "deepcanvas/server_core/cell_diff.hpp"

namespace deepcanvas::exporting {

namespace {

namespace dm = protocol::density;
using server_core::CellCoord;
using server_core::CellPaste;
using server_core::OctreeConfig;

Error bad_file(const std::string& format, const std::string& why) {
  return Error{Errc::malformed, "the " + format + " file: " + why};
}

// A library's exception text for an error message that goes back to the client: printable
// ASCII only, runs of spaces as one, at most kMaxDetail characters. Why: OpenVDB's text for a
// cut-short file quotes the bytes it read as a grid type, 32 KB of whatever followed (an
// AddressSanitizer build read different bytes there than a release build), and a reply of
// that size and content never reached the client, which waited out its timeout.
constexpr std::size_t kMaxDetail = 160;
std::string library_detail(const char* what) {
  std::string out;
  for (const char* c = what; *c != '\0' && out.size() < kMaxDetail; ++c) {
    const unsigned char ch = static_cast<unsigned char>(*c);
    const char put = ch >= 0x20 && ch < 0x7f ? *c : ' ';
    if (put == ' ' && (out.empty() || out.back() == ' ')) continue;
    out += put;
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  if (std::strlen(what) > kMaxDetail) out += "...";
  return out;
}

// What a grid's values are.
enum class Values { extinction, coverage };

// The grids to import, in canvas metres (`xf` maps their index space to canvas metres).
struct Source {
  openvdb::FloatGrid::Ptr grid;     // extinction per metre, or coverage 0..1
  openvdb::Vec3SGrid::Ptr colour;   // optional, same index space as `grid`
  Values values = Values::extinction;
  double sigma_scale = 1;           // extinction per metre = value x this
  std::string what;
};

double cell_edge(const OctreeConfig& c, int depth) {
  return c.edge_m / c.roots_per_axis / static_cast<double>(std::uint64_t{1} << depth);
}

int nearest_level(const OctreeConfig& c, double edge_m) {
  const double root = c.edge_m / c.roots_per_axis;
  return std::clamp(static_cast<int>(std::lround(std::log2(root / edge_m))), 0, c.max_depth);
}

std::uint32_t byte_of(double v) {
  return static_cast<std::uint32_t>(std::clamp(std::lround(v * 255.0), 0L, 255L));
}

// Turns the source's active values into cells at depth D (see the header: a voxel's box covers
// the coarsest cells inside it, and at D the cells whose centres it holds).
class Rasterizer {
 public:
  Rasterizer(const OctreeConfig& c, int D, const ImportOptions& o, const Source& s)
      : c_(c), D_(D), o_(o), s_(s) {}

  Result<CellPaste> run() {
    const openvdb::math::Transform& xf = s_.grid->transform();
    const auto colour = s_.colour ? std::optional(s_.colour->getConstAccessor()) : std::nullopt;
    const double half = c_.edge_m / 2;
    openvdb::Coord node(std::numeric_limits<int>::max());
    for (auto it = s_.grid->cbeginValueOn(); it; ++it) {
      // Cells are coalesced an OpenVDB leaf node (8^3 voxels) at a time, as they come, so that
      // a finely written volume never holds all of its voxels as cells at once.
      const openvdb::Coord here =
          it.isVoxelValue() ? openvdb::Coord(it.getCoord().x() & ~7, it.getCoord().y() & ~7,
                                             it.getCoord().z() & ~7)
                            : openvdb::Coord(std::numeric_limits<int>::min());
      if (here != node || !it.isVoxelValue()) {
        if (auto r = flush(); !r) return std::move(r).error();
        node = here;
      }
      const float value = *it;
      if (!std::isfinite(value)) return bad_file("vdb", "a value is NaN or infinite");
      if (value <= 0) continue;
      openvdb::CoordBBox bb;
      it.getBoundingBox(bb);
      const openvdb::Vec3d lo = xf.indexToWorld(bb.min().asVec3d() - openvdb::Vec3d(0.5));
      const openvdb::Vec3d hi = xf.indexToWorld(bb.max().asVec3d() + openvdb::Vec3d(0.5));
      Box box;
      for (int a = 0; a < 3; ++a) {
        box.lo[a] = std::min(lo[a], hi[a]);
        box.hi[a] = std::max(lo[a], hi[a]);
        if (!(box.lo[a] >= -half && box.hi[a] <= half))
          return make_error(Errc::invalid_argument,
                            "the import falls outside the canvas (a voxel at " +
                                std::to_string(box.lo[a]) + " m on axis " + "xyz"[a] +
                                "; the canvas spans +-" + std::to_string(half) +
                                " m): choose another --at or a smaller --scale");
      }
      openvdb::Vec3s rgb(o_.colour[0], o_.colour[1], o_.colour[2]);
      if (colour) rgb = colour->getValue(openvdb::Coord((bb.min().asVec3i() + bb.max().asVec3i()) / 2));
      value_ = value;
      rgb_ = (byte_of(rgb[0])) | (byte_of(rgb[1]) << 8) | (byte_of(rgb[2]) << 16);
      if (auto r = cover(box); !r) return std::move(r).error();
    }
    if (auto r = flush(); !r) return std::move(r).error();
    coalesce(entries_);
    // Float rounding at shared faces could name a cell twice, or one inside another: the first
    // in address order (the coarser) is kept. Alpha is quantised last, at each cell's own depth.
    std::sort(entries_.begin(), entries_.end(),
              [](const Entry& a, const Entry& b) { return server_core::cell_order(a.k, b.k); });
    std::unordered_set<CellCoord, server_core::CellCoordHash> seen;
    std::uint32_t depths = 0;
    for (const Entry& e : entries_) {
      bool inside = false;
      for (CellCoord up = e.k;; up = server_core::parent_coord(up)) {
        if (((depths >> up.depth) & 1u) && seen.count(up)) inside = true;
        if (inside || up.depth == 0) break;
      }
      if (inside) continue;
      const std::uint32_t v = rgba_of(e);
      if ((v >> 24) == 0) continue;
      seen.insert(e.k);
      depths |= 1u << e.k.depth;
      paste_.cells.push_back({e.k, v});
    }
    if (auto r = server_core::normalise_cell_paste(paste_, c_, o_.max_cells); !r)
      return std::move(r).error();
    return std::move(paste_);
  }

 private:
  struct Box {
    double lo[3], hi[3];
  };

  // A cell before quantisation: the grid's value (extinction or coverage) and the colour.
  struct Entry {
    CellCoord k;
    float value;
    std::uint32_t rgb;
  };

  std::uint32_t rgba_of(const Entry& e) const {
    double a = 0;
    if (s_.values == Values::coverage) {
      a = std::clamp(static_cast<double>(e.value), 0.0, 1.0);
    } else {
      const double sigma = e.value * s_.sigma_scale;
      a = 1.0 - std::exp(-sigma * cell_edge(c_, e.k.depth));
    }
    return (byte_of(a) << 24) | e.rgb;
  }

  Result<void> emit(const CellCoord& k) {
    // A voxel far larger than the level's cells: bounded before anything grows.
    if (pending_.size() >= o_.max_cells) return too_many();
    pending_.push_back({k, value_, rgb_});
    return {};
  }
  Error too_many() const {
    return make_error(Errc::limit_exceeded, "the import makes more than " +
                                                std::to_string(o_.max_cells) +
                                                " cells: choose a coarser --voxel-size");
  }
  // The cells of the last leaf node (or tile), coalesced, join the rest.
  Result<void> flush() {
    if (pending_.empty()) return {};
    coalesce(pending_);
    if (entries_.size() + pending_.size() > o_.max_cells) return too_many();
    entries_.insert(entries_.end(), pending_.begin(), pending_.end());
    pending_.clear();
    return {};
  }

  // Eight sibling cells with the same value and colour are their parent (the same paint: the
  // density model's extinction does not depend on the cell size), deepest level first; so a
  // coarse cell written as voxels comes back as that one cell, its alpha quantised once.
  static void coalesce(std::vector<Entry>& entries_) {
    for (int d = entries_.empty() ? 0 : std::max_element(entries_.begin(), entries_.end(),
                                                          [](const Entry& a, const Entry& b) {
                                                            return a.k.depth < b.k.depth;
                                                          })->k.depth;
         d > 0; --d) {
      std::unordered_map<CellCoord, std::vector<std::size_t>, server_core::CellCoordHash> groups;
      for (std::size_t i = 0; i < entries_.size(); ++i)
        if (entries_[i].k.depth == d) groups[server_core::parent_coord(entries_[i].k)].push_back(i);
      if (groups.empty()) continue;
      std::vector<std::uint8_t> drop(entries_.size(), 0);
      std::vector<Entry> parents;
      for (const auto& [parent, members] : groups) {
        if (members.size() != 8) continue;
        const Entry& first = entries_[members[0]];
        bool same = true;
        for (std::size_t m : members)
          same = same && entries_[m].value == first.value && entries_[m].rgb == first.rgb;
        if (!same) continue;
        for (std::size_t m : members) drop[m] = 1;
        parents.push_back({parent, first.value, first.rgb});
      }
      if (parents.empty()) continue;
      std::vector<Entry> kept;
      kept.reserve(entries_.size() - 7 * parents.size());
      for (std::size_t i = 0; i < entries_.size(); ++i)
        if (!drop[i]) kept.push_back(entries_[i]);
      kept.insert(kept.end(), parents.begin(), parents.end());
      entries_ = std::move(kept);
    }
  }

  Result<void> cover(const Box& b) {
    const double half = c_.edge_m / 2;
    const double root = c_.edge_m / c_.roots_per_axis;
    // The root cells the box meets, then down.
    std::uint32_t r0[3], r1[3];
    for (int a = 0; a < 3; ++a) {
      r0[a] = static_cast<std::uint32_t>(std::clamp(std::floor((b.lo[a] + half) / root), 0.0,
                                                    c_.roots_per_axis - 1.0));
      r1[a] = static_cast<std::uint32_t>(std::clamp(std::floor((b.hi[a] + half) / root), 0.0,
                                                    c_.roots_per_axis - 1.0));
    }
    stack_.clear();
    for (std::uint32_t z = r0[2]; z <= r1[2]; ++z)
      for (std::uint32_t y = r0[1]; y <= r1[1]; ++y)
        for (std::uint32_t x = r0[0]; x <= r1[0]; ++x) stack_.push_back({0, x, y, z});
    while (!stack_.empty()) {
      const CellCoord k = stack_.back();
      stack_.pop_back();
      const double e = cell_edge(c_, k.depth);
      const double lo[3] = {-half + k.x * e, -half + k.y * e, -half + k.z * e};
      bool meets = true, within = true, centre_in = true;
      for (int a = 0; a < 3; ++a) {
        meets = meets && lo[a] < b.hi[a] && lo[a] + e > b.lo[a];
        within = within && lo[a] >= b.lo[a] && lo[a] + e <= b.hi[a];
        const double mid = lo[a] + e / 2;
        centre_in = centre_in && mid >= b.lo[a] && mid < b.hi[a];
      }
      if (!meets) continue;
      if (within || k.depth == D_) {
        if (within || centre_in)
          if (auto r = emit(k); !r) return r;
        continue;
      }
      for (std::uint32_t i = 0; i < 8; ++i) stack_.push_back(server_core::child_coord(k, i));
    }
    return {};
  }

  const OctreeConfig& c_;
  const int D_;
  const ImportOptions& o_;
  const Source& s_;
  float value_ = 0;
  std::uint32_t rgb_ = 0;
  std::vector<CellCoord> stack_;
  std::vector<Entry> entries_, pending_;
  CellPaste paste_;
};

// A level set (signed distance, negative inside) as coverage: a ramp one voxel wide across the
// surface, 1 inside (interior tiles included).
openvdb::FloatGrid::Ptr coverage_of_level_set(const openvdb::FloatGrid& sdf) {
  const double h = sdf.voxelSize()[0];
  auto out = openvdb::FloatGrid::create(0.0f);
  out->setTransform(sdf.transform().copy());
  auto inside = openvdb::tools::sdfInteriorMask(sdf);
  for (auto it = inside->cbeginValueOn(); it; ++it) {
    openvdb::CoordBBox bb;
    it.getBoundingBox(bb);
    if (it.isTileValue())
      out->tree().sparseFill(bb, 1.0f, true);
    else
      out->tree().setValue(it.getCoord(), 1.0f);
  }
  for (auto it = sdf.cbeginValueOn(); it; ++it) {
    if (!it.isVoxelValue()) continue;
    const double a = std::clamp(0.5 - *it / h, 0.0, 1.0);
    if (a > 0)
      out->tree().setValue(it.getCoord(), static_cast<float>(a));
    else
      out->tree().setValueOff(it.getCoord(), 0.0f);
  }
  return out;
}

// Canvas metres from file units: p -> at + scale * p, applied to a grid's transform.
Result<void> place(openvdb::GridBase& g, const ImportOptions& o) {
  auto& xf = g.transform();
  if (!xf.isLinear()) return make_error(Errc::invalid_argument, "the grid's transform is not linear");
  const openvdb::Vec3d vs = xf.voxelSize();
  if (std::abs(vs[0] - vs[1]) > 1e-9 * vs[0] || std::abs(vs[0] - vs[2]) > 1e-9 * vs[0])
    return make_error(Errc::invalid_argument, "the grid's voxels are not cubes");
  xf.postScale(o.scale);
  xf.postTranslate(openvdb::Vec3d(o.at[0], o.at[1], o.at[2]));
  return {};
}

// The bytes in a file of our own, for OpenVDB to map: it reads with delayed loading (read
// without it, a cut-short file makes OpenVDB leak the node it was reading when it throws), and
// an io::Stream would copy the bytes to /tmp/openvdb_temp_* itself, a copy left behind when
// the read throws or the process is killed. This file is removed as soon as OpenVDB has it
// open (the mapping keeps its bytes), and on every error path.
class MappedCopy {
 public:
  static Result<MappedCopy> write(std::span<const std::uint8_t> bytes) {
    const char* dir = std::getenv("TMPDIR");
    std::string path = std::string(dir != nullptr && *dir != '\0' ? dir : "/tmp") +
                       "/deepcanvas-import-XXXXXX";
    const int fd = ::mkstemp(path.data());
    if (fd < 0)
      return make_error(Errc::io_error, "cannot make a temporary file for the vdb file in " +
                                            path.substr(0, path.rfind('/')) + ": " +
                                            std::strerror(errno));
    MappedCopy copy(path);
    std::size_t done = 0;
    while (done < bytes.size()) {
      const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        const int err = errno;
        ::close(fd);
        return make_error(Errc::io_error, "cannot write the temporary copy of the vdb file " +
                                              path + ": " + std::strerror(err));
      }
      done += static_cast<std::size_t>(n);
    }
    if (::close(fd) != 0)
      return make_error(Errc::io_error, "cannot write the temporary copy of the vdb file " +
                                            path + ": " + std::strerror(errno));
    return copy;
  }
  MappedCopy(MappedCopy&& o) noexcept : path_(std::exchange(o.path_, {})) {}
  MappedCopy& operator=(MappedCopy&&) = delete;
  ~MappedCopy() { remove(); }
  const std::string& path() const noexcept { return path_; }
  void remove() noexcept {
    if (!path_.empty()) ::unlink(path_.c_str());
    path_.clear();
  }

 private:
  explicit MappedCopy(std::string path) : path_(std::move(path)) {}
  std::string path_;
};

Result<Source> read_vdb(std::span<const std::uint8_t> bytes, const ImportOptions& o) {
  auto copy = MappedCopy::write(bytes);
  if (!copy) return std::move(copy).error();
  openvdb::GridPtrVecPtr grids;
  try {
    openvdb::io::File file(copy->path());
    file.setCopyMaxBytes(0);  // the file is ours: no second copy
    file.open(/*delayLoad=*/true);
    copy->remove();
    grids = file.getGrids();
    file.close();
  } catch (const std::exception& e) {
    return bad_file("vdb", "not a readable OpenVDB file (" + library_detail(e.what()) + ")");
  }
  if (!grids || grids->empty()) return bad_file("vdb", "holds no grids");
  Source s;
  std::string found;
  for (const auto& g : *grids) {
    found += (found.empty() ? "" : ", ") + g->getName() + " (" + g->valueType() + ")";
    auto f = openvdb::gridPtrCast<openvdb::FloatGrid>(g);
    if (f && (!s.grid || g->getName() == "density")) s.grid = f;
    auto v = openvdb::gridPtrCast<openvdb::Vec3SGrid>(g);
    const std::string n = g->getName();
    if (v && (n == "Cd" || n == "color" || n == "colour")) s.colour = v;
  }
  if (!s.grid)
    return make_error(Errc::invalid_argument,
                      "the vdb file has no float grid to import (it holds: " + found + ")");
  s.what = "grid " + s.grid->getName();
  if (s.grid->getGridClass() == openvdb::GRID_LEVEL_SET) {
    if (auto r = place(*s.grid, o); !r) return std::move(r).error();
    s.grid = coverage_of_level_set(*s.grid);
    s.values = Values::coverage;
    s.what += " (level set)";
  } else {
    if (auto r = place(*s.grid, o); !r) return std::move(r).error();
    s.values = Values::extinction;
    // Extinction per file unit -> per metre.
    s.sigma_scale = o.density_scale / o.scale;
    s.what += " (fog volume)";
  }
  if (s.colour) {
    if (auto r = place(*s.colour, o); !r) return std::move(r).error();
    if (s.colour->transform() != s.grid->transform()) {
      s.colour.reset();  // another index space: not sampled (options.colour instead)
    } else {
      s.what += " + " + s.colour->getName();
    }
  }
  return s;
}

// A mesh as a solid in canvas metres at depth D, with the nearest triangle's colours.
Result<Source> read_solid_mesh(std::span<const std::uint8_t> bytes, const OctreeConfig& c,
                               const ImportOptions& o, int& D) {
  auto m = read_mesh_bytes(bytes, o.format);
  if (!m) return std::move(m).error();
  if (m->indices.empty()) return bad_file(o.format, "the mesh has no triangles");
  std::vector<openvdb::Vec3s> points(m->positions.size());
  double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
  for (std::size_t i = 0; i < points.size(); ++i)
    for (int a = 0; a < 3; ++a) {
      const double v = o.at[static_cast<std::size_t>(a)] + o.scale * m->positions[i][static_cast<std::size_t>(a)];
      points[i][a] = static_cast<float>(v);
      lo[a] = std::min(lo[a], v);
      hi[a] = std::max(hi[a], v);
    }
  const double half = c.edge_m / 2;
  for (int a = 0; a < 3; ++a)
    if (!(lo[a] >= -half && hi[a] <= half))
      return make_error(Errc::invalid_argument,
                        "the mesh falls outside the canvas (it reaches " +
                            std::to_string(lo[a] < -half ? lo[a] : hi[a]) + " m on axis " +
                            "xyz"[a] + "): choose another --at or a smaller --scale");
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  D = nearest_level(c, o.voxel_size_m > 0 ? o.voxel_size_m : std::max(extent / 128, 1e-12));
  const double h = cell_edge(c, D);
  // OpenVDB's mesh-to-volume takes points in index space.
  for (auto& q : points)
    for (int a = 0; a < 3; ++a) q[a] = static_cast<float>((q[a] - (-half + 0.5 * h)) / h);
  std::vector<openvdb::Vec3I> tris(m->triangles());
  for (std::size_t t = 0; t < tris.size(); ++t)
    tris[t] = openvdb::Vec3I(m->indices[3 * t], m->indices[3 * t + 1], m->indices[3 * t + 2]);
  // The index space of the canvas's cells at depth D: voxel (i, j, k) is cell (D, i, j, k).
  auto xf = openvdb::math::Transform::createLinearTransform(h);
  xf->postTranslate(openvdb::Vec3d(-half + 0.5 * h));
  openvdb::Int32Grid nearest(0);
  openvdb::FloatGrid::Ptr sdf;
  try {
    openvdb::tools::QuadAndTriangleDataAdapter<openvdb::Vec3s, openvdb::Vec3I> adapter(points, tris);
    sdf = openvdb::tools::meshToVolume<openvdb::FloatGrid>(adapter, *xf, 3.0f, 3.0f, 0, &nearest);
  } catch (const std::exception& e) {
    return bad_file(o.format, "the mesh did not convert (" + library_detail(e.what()) + ")");
  }
  Source s;
  s.grid = coverage_of_level_set(*sdf);
  s.values = Values::coverage;
  // Colours: the nearest triangle's vertex colours (mean) near the surface; inside, the mean of
  // the mesh's colours.
  openvdb::Vec3d mean(0.0);
  for (const auto& col : m->colours) mean += openvdb::Vec3d(col[0], col[1], col[2]) / 255.0;
  mean /= static_cast<double>(std::max<std::size_t>(1, m->colours.size()));
  s.colour = openvdb::Vec3SGrid::create(openvdb::Vec3s(mean));
  s.colour->setTransform(s.grid->transform().copy());
  auto acc = nearest.getConstAccessor();
  for (auto it = s.grid->cbeginValueOn(); it; ++it) {
    if (!it.isVoxelValue()) continue;
    const openvdb::Int32 t = acc.getValue(it.getCoord());
    if (!acc.isValueOn(it.getCoord()) || t < 0 || static_cast<std::size_t>(t) >= tris.size()) continue;
    openvdb::Vec3d rgb(0.0);
    for (int k = 0; k < 3; ++k) {
      const auto& col = m->colours[tris[static_cast<std::size_t>(t)][k]];
      rgb += openvdb::Vec3d(col[0], col[1], col[2]) / (3 * 255.0);
    }
    s.colour->tree().setValue(it.getCoord(), openvdb::Vec3s(rgb));
  }
  s.what = "mesh: " + std::to_string(tris.size()) + " triangles";
  return s;
}

Result<void> check_options(const ImportOptions& o) {
  for (double v : o.at)
    if (!std::isfinite(v)) return make_error(Errc::invalid_argument, "--at must be finite");
  if (!(o.scale > 0 && o.scale <= 1e9)) return make_error(Errc::invalid_argument, "--scale must lie in (0, 1e9]");
  if (!(o.voxel_size_m >= 0 && std::isfinite(o.voxel_size_m)))
    return make_error(Errc::invalid_argument, "--voxel-size must be positive");
  if (!(o.density_scale > 0 && o.density_scale <= 1e9))
    return make_error(Errc::invalid_argument, "--density-scale must lie in (0, 1e9]");
  for (float v : o.colour)
    if (!(v >= 0 && v <= 1)) return make_error(Errc::invalid_argument, "--colour values lie in 0..1");
  if (o.format != "vdb" && o.format != "gltf" && o.format != "glb" && o.format != "ply")
    return make_error(Errc::invalid_argument, "format " + o.format + ": not vdb, gltf, glb or ply");
  return {};
}

}  // namespace

Result<CellPaste> import_cells(std::span<const std::uint8_t> file, const OctreeConfig& canvas,
                               const ImportOptions& options, ImportSummary* summary) {
  if (auto r = check_options(options); !r) return std::move(r).error();
  if (file.empty()) return bad_file(options.format, "empty");
  openvdb::initialize();
  int D = 0;
  Result<Source> src = Error{};
  if (options.format == "vdb") {
    src = read_vdb(file, options);
    if (src) {
      const double vs = src->grid->voxelSize()[0];
      D = nearest_level(canvas, options.voxel_size_m > 0 ? options.voxel_size_m : vs);
    }
  } else {
    src = read_solid_mesh(file, canvas, options, D);
  }
  if (!src) return std::move(src).error();
  Result<CellPaste> cells = Error{};
  try {
    cells = Rasterizer(canvas, D, options, *src).run();
  } catch (const std::exception& e) {
    return bad_file(options.format, "reading its grid failed (" + library_detail(e.what()) + ")");
  }
  if (!cells) return cells;
  if (cells->cells.empty())
    return make_error(Errc::invalid_argument, "the file holds nothing to paint (every value is 0)");
  if (summary != nullptr) {
    summary->depth = D;
    summary->cell_edge_m = cell_edge(canvas, D);
    summary->cells = cells->size();
    summary->source = src->what;
  }
  return cells;
}

}  // namespace deepcanvas::exporting
