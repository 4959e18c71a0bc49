// Mesh files: glTF 2.0 through tinygltf, and binary PLY (mesh_export.hpp has the layouts).
#include <tiny_gltf.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "deepcanvas/export/mesh_export.hpp"

namespace deepcanvas::exporting {

namespace {

namespace fs = std::filesystem;

template <class T>
void append(std::vector<unsigned char>& out, const T* data, std::size_t n) {
  const auto* b = reinterpret_cast<const unsigned char*>(data);
  out.insert(out.end(), b, b + n * sizeof(T));
}

Result<void> write_gltf(const Mesh& m, bool binary, const std::string& path) {
  tinygltf::Model model;
  model.asset.version = "2.0";
  model.asset.generator = "deepcanvas-server export";
  tinygltf::Buffer buffer;
  const std::size_t n = m.positions.size();
  append(buffer.data, m.positions.data(), n);
  std::vector<float> colours(3 * n);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t c = 0; c < 3; ++c) colours[3 * i + c] = m.colours[i][c] / 255.0f;
  append(buffer.data, colours.data(), colours.size());
  append(buffer.data, m.indices.data(), m.indices.size());
  model.buffers.push_back(std::move(buffer));
  const std::size_t vbytes = n * 12;
  auto view = [&](std::size_t offset, std::size_t length, int target) {
    tinygltf::BufferView v;
    v.buffer = 0;
    v.byteOffset = offset;
    v.byteLength = length;
    v.target = target;
    model.bufferViews.push_back(v);
    return static_cast<int>(model.bufferViews.size() - 1);
  };
  const int pv = view(0, vbytes, TINYGLTF_TARGET_ARRAY_BUFFER);
  const int cv = view(vbytes, vbytes, TINYGLTF_TARGET_ARRAY_BUFFER);
  const int iv = view(2 * vbytes, m.indices.size() * 4, TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER);
  auto accessor = [&](int v, int component, int type, std::size_t count) {
    tinygltf::Accessor a;
    a.bufferView = v;
    a.componentType = component;
    a.type = type;
    a.count = count;
    model.accessors.push_back(a);
    return static_cast<int>(model.accessors.size() - 1);
  };
  const int pa = accessor(pv, TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3, n);
  // glTF requires the positions' bounds.
  std::array<double, 3> lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};
  for (const auto& p : m.positions)
    for (std::size_t c = 0; c < 3; ++c) {
      lo[c] = std::min(lo[c], static_cast<double>(p[c]));
      hi[c] = std::max(hi[c], static_cast<double>(p[c]));
    }
  model.accessors[static_cast<std::size_t>(pa)].minValues.assign(lo.begin(), lo.end());
  model.accessors[static_cast<std::size_t>(pa)].maxValues.assign(hi.begin(), hi.end());
  const int ca = accessor(cv, TINYGLTF_COMPONENT_TYPE_FLOAT, TINYGLTF_TYPE_VEC3, n);
  const int ia = accessor(iv, TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT, TINYGLTF_TYPE_SCALAR,
                          m.indices.size());
  tinygltf::Primitive prim;
  prim.attributes["POSITION"] = pa;
  prim.attributes["COLOR_0"] = ca;
  prim.indices = ia;
  prim.mode = TINYGLTF_MODE_TRIANGLES;
  tinygltf::Mesh mesh;
  mesh.name = "canvas";
  mesh.primitives.push_back(prim);
  model.meshes.push_back(mesh);
  tinygltf::Node node;
  node.mesh = 0;
  node.name = "canvas";
  model.nodes.push_back(node);
  tinygltf::Scene scene;
  scene.nodes.push_back(0);
  model.scenes.push_back(scene);
  model.defaultScene = 0;
  tinygltf::TinyGLTF gltf;
  if (!gltf.WriteGltfSceneToFile(&model, path, /*embedImages=*/true, /*embedBuffers=*/true,
                                 /*prettyPrint=*/false, binary))
    return make_error(Errc::io_error, "writing " + path + " failed");
  return {};
}

Result<void> write_ply(const Mesh& m, const std::string& path) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) return make_error(Errc::io_error, "cannot create " + path);
  f << "ply\nformat binary_little_endian 1.0\ncomment deepcanvas-server export\n"
    << "element vertex " << m.positions.size() << "\n"
    << "property float x\nproperty float y\nproperty float z\n"
    << "property uchar red\nproperty uchar green\nproperty uchar blue\n"
    << "element face " << m.triangles() << "\nproperty list uchar int vertex_indices\n"
    << "end_header\n";
  std::vector<char> buf;
  buf.reserve(m.positions.size() * 15 + m.triangles() * 13);
  for (std::size_t i = 0; i < m.positions.size(); ++i) {
    const char* p = reinterpret_cast<const char*>(m.positions[i].data());
    buf.insert(buf.end(), p, p + 12);
    const char* c = reinterpret_cast<const char*>(m.colours[i].data());
    buf.insert(buf.end(), c, c + 3);
  }
  for (std::size_t t = 0; t < m.triangles(); ++t) {
    buf.push_back(3);
    const char* p = reinterpret_cast<const char*>(&m.indices[3 * t]);
    buf.insert(buf.end(), p, p + 12);
  }
  f.write(buf.data(), static_cast<std::streamsize>(buf.size()));
  f.close();
  if (!f) return make_error(Errc::io_error, "writing " + path + " failed (disk full?)");
  return {};
}

bool has_suffix(const std::string& s, const std::string& suffix) {
  if (s.size() < suffix.size()) return false;
  std::string tail = s.substr(s.size() - suffix.size());
  std::transform(tail.begin(), tail.end(), tail.begin(), ::tolower);
  return tail == suffix;
}

Error bad(const std::string& path, const std::string& why) {
  return Error{Errc::malformed, path + ": " + why};
}

// The float VEC3 data of an accessor, checked against its view and buffer.
Result<std::vector<std::array<float, 3>>> vec3s(const tinygltf::Model& model, int index,
                                                const std::string& path, const char* what) {
  if (index < 0 || static_cast<std::size_t>(index) >= model.accessors.size())
    return bad(path, std::string("no ") + what + " accessor");
  const auto& a = model.accessors[static_cast<std::size_t>(index)];
  if (a.type != TINYGLTF_TYPE_VEC3 || a.bufferView < 0 ||
      static_cast<std::size_t>(a.bufferView) >= model.bufferViews.size())
    return bad(path, std::string(what) + " is not a stored VEC3");
  const auto& v = model.bufferViews[static_cast<std::size_t>(a.bufferView)];
  if (v.buffer < 0 || static_cast<std::size_t>(v.buffer) >= model.buffers.size())
    return bad(path, std::string(what) + ": no buffer");
  const auto& b = model.buffers[static_cast<std::size_t>(v.buffer)].data;
  const int csize = tinygltf::GetComponentSizeInBytes(static_cast<std::uint32_t>(a.componentType));
  if (csize <= 0) return bad(path, std::string(what) + ": unknown component type");
  const std::size_t stride = v.byteStride != 0 ? v.byteStride : 3 * static_cast<std::size_t>(csize);
  const std::size_t begin = v.byteOffset + a.byteOffset;
  if (a.count > 0 && (begin + (a.count - 1) * stride + 3 * static_cast<std::size_t>(csize) >
                          std::min(b.size(), v.byteOffset + v.byteLength)))
    return bad(path, std::string(what) + " runs past its buffer");
  std::vector<std::array<float, 3>> out(a.count);
  for (std::size_t i = 0; i < a.count; ++i) {
    const unsigned char* p = b.data() + begin + i * stride;
    for (std::size_t c = 0; c < 3; ++c) {
      float x = 0;
      switch (a.componentType) {
        case TINYGLTF_COMPONENT_TYPE_FLOAT:
          std::memcpy(&x, p + 4 * c, 4);
          break;
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
          x = p[c] / 255.0f;
          break;
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
          std::uint16_t u;
          std::memcpy(&u, p + 2 * c, 2);
          x = u / 65535.0f;
          break;
        }
        default:
          return bad(path, std::string(what) + ": unsupported component type");
      }
      if (!std::isfinite(x)) return bad(path, std::string(what) + " holds NaN or infinity");
      out[i][c] = x;
    }
  }
  return out;
}

Result<Mesh> read_gltf(std::span<const std::uint8_t> bytes, const std::string& path, bool binary) {
  tinygltf::Model model;
  tinygltf::TinyGLTF gltf;
  std::string err, warn;
  if (bytes.size() > (std::size_t{1} << 31)) return bad(path, "larger than 2 GiB");
  const auto n = static_cast<unsigned int>(bytes.size());
  // No external files: buffers and images must be embedded (base_dir is empty).
  const bool ok = binary ? gltf.LoadBinaryFromMemory(&model, &err, &warn, bytes.data(), n, "")
                         : gltf.LoadASCIIFromString(&model, &err, &warn,
                                                    reinterpret_cast<const char*>(bytes.data()), n,
                                                    "");
  if (!ok) return bad(path, "not a readable glTF file: " + (err.empty() ? warn : err));
  if (model.meshes.empty() || model.meshes[0].primitives.empty())
    return bad(path, "holds no mesh");
  const auto& prim = model.meshes[0].primitives[0];
  if (prim.mode != TINYGLTF_MODE_TRIANGLES && prim.mode != -1)
    return bad(path, "the first primitive is not triangles");
  const auto pos = prim.attributes.find("POSITION");
  if (pos == prim.attributes.end()) return bad(path, "the mesh has no POSITION");
  Mesh m;
  auto p = vec3s(model, pos->second, path, "POSITION");
  if (!p) return std::move(p).error();
  m.positions = std::move(*p);
  m.colours.assign(m.positions.size(), {255, 255, 255});
  if (const auto col = prim.attributes.find("COLOR_0"); col != prim.attributes.end()) {
    auto c = vec3s(model, col->second, path, "COLOR_0");
    if (!c) return std::move(c).error();
    if (c->size() != m.positions.size()) return bad(path, "COLOR_0 and POSITION differ in count");
    for (std::size_t i = 0; i < c->size(); ++i)
      for (std::size_t k = 0; k < 3; ++k)
        m.colours[i][k] = static_cast<std::uint8_t>(
            std::clamp(std::lround((*c)[i][k] * 255.0f), 0L, 255L));
  }
  if (prim.indices < 0) {
    if (m.positions.size() % 3 != 0) return bad(path, "unindexed vertices not a multiple of 3");
    for (std::uint32_t i = 0; i < m.positions.size(); ++i) m.indices.push_back(i);
    return m;
  }
  if (static_cast<std::size_t>(prim.indices) >= model.accessors.size())
    return bad(path, "no index accessor");
  const auto& a = model.accessors[static_cast<std::size_t>(prim.indices)];
  if (a.type != TINYGLTF_TYPE_SCALAR || a.bufferView < 0 ||
      static_cast<std::size_t>(a.bufferView) >= model.bufferViews.size() || a.count % 3 != 0)
    return bad(path, "the indices are not a stored list of triangles");
  const auto& v = model.bufferViews[static_cast<std::size_t>(a.bufferView)];
  if (v.buffer < 0 || static_cast<std::size_t>(v.buffer) >= model.buffers.size())
    return bad(path, "indices: no buffer");
  const auto& b = model.buffers[static_cast<std::size_t>(v.buffer)].data;
  const int csize = tinygltf::GetComponentSizeInBytes(static_cast<std::uint32_t>(a.componentType));
  if (csize != 1 && csize != 2 && csize != 4) return bad(path, "indices: unknown component type");
  const std::size_t begin = v.byteOffset + a.byteOffset;
  if (begin + a.count * static_cast<std::size_t>(csize) > std::min(b.size(), v.byteOffset + v.byteLength))
    return bad(path, "the indices run past their buffer");
  m.indices.resize(a.count);
  for (std::size_t i = 0; i < a.count; ++i) {
    std::uint32_t x = 0;
    std::memcpy(&x, b.data() + begin + i * static_cast<std::size_t>(csize),
                static_cast<std::size_t>(csize));
    if (x >= m.positions.size()) return bad(path, "an index past the vertices");
    m.indices[i] = x;
  }
  return m;
}

// Binary little-endian PLY: vertex x y z (float or double) with optional uchar red green blue,
// and faces as a list (triangles; polygons fanned).
Result<Mesh> read_ply(std::span<const std::uint8_t> bytes, const std::string& path) {
  std::istringstream f(std::string(reinterpret_cast<const char*>(bytes.data()), bytes.size()),
                       std::ios::binary);
  std::string line;
  std::getline(f, line);
  if (line != "ply") return bad(path, "not a PLY file");
  std::uint64_t nv = 0, nf = 0;
  struct Prop {
    std::string name, type;
  };
  std::vector<Prop> vprops;
  std::string element, face_count_type, face_index_type;
  bool binary_le = false;
  while (std::getline(f, line)) {
    std::istringstream in(line);
    std::string w;
    in >> w;
    if (w == "format") {
      std::string fmt;
      in >> fmt;
      binary_le = fmt == "binary_little_endian";
    } else if (w == "element") {
      std::uint64_t n = 0;
      in >> element >> n;
      if (element == "vertex") nv = n;
      if (element == "face") nf = n;
    } else if (w == "property") {
      std::string t;
      in >> t;
      if (t == "list") {
        if (element == "face") in >> face_count_type >> face_index_type;
      } else if (element == "vertex") {
        Prop p;
        p.type = t;
        in >> p.name;
        vprops.push_back(p);
      }
    } else if (w == "end_header") {
      break;
    }
    if (line.size() > 4096) return bad(path, "a header line too long");
  }
  if (!binary_le) return bad(path, "only binary little-endian PLY is read");
  if (nv > (std::uint64_t{1} << 28) || nf > (std::uint64_t{1} << 28))
    return bad(path, "absurd vertex or face count");
  auto size_of = [](const std::string& t) -> int {
    if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
    if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
    if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" ||
        t == "float32")
      return 4;
    if (t == "double" || t == "float64") return 8;
    return 0;
  };
  std::size_t vsize = 0;
  for (const auto& p : vprops) {
    if (size_of(p.type) == 0) return bad(path, "unknown property type " + p.type);
    vsize += static_cast<std::size_t>(size_of(p.type));
  }
  Mesh m;
  m.positions.resize(nv);
  m.colours.assign(nv, {255, 255, 255});
  std::vector<unsigned char> rec(vsize);
  for (std::uint64_t i = 0; i < nv; ++i) {
    if (!f.read(reinterpret_cast<char*>(rec.data()), static_cast<std::streamsize>(vsize)))
      return bad(path, "truncated in the vertices");
    std::size_t off = 0;
    for (const auto& p : vprops) {
      double x = 0;
      if (p.type == "float" || p.type == "float32") {
        float v;
        std::memcpy(&v, &rec[off], 4);
        x = v;
      } else if (p.type == "double" || p.type == "float64") {
        std::memcpy(&x, &rec[off], 8);
      } else if (size_of(p.type) == 1) {
        x = rec[off];
      }
      if (!std::isfinite(x)) return bad(path, "a vertex holds NaN or infinity");
      if (p.name == "x") m.positions[i][0] = static_cast<float>(x);
      if (p.name == "y") m.positions[i][1] = static_cast<float>(x);
      if (p.name == "z") m.positions[i][2] = static_cast<float>(x);
      if (p.name == "red") m.colours[i][0] = static_cast<std::uint8_t>(x);
      if (p.name == "green") m.colours[i][1] = static_cast<std::uint8_t>(x);
      if (p.name == "blue") m.colours[i][2] = static_cast<std::uint8_t>(x);
      off += static_cast<std::size_t>(size_of(p.type));
    }
  }
  const int cs = size_of(face_count_type), is = size_of(face_index_type);
  if (nf > 0 && ((cs != 1 && cs != 2 && cs != 4) || (is != 1 && is != 2 && is != 4)))
    return bad(path, "faces: unknown list types");
  for (std::uint64_t i = 0; i < nf; ++i) {
    std::uint32_t count = 0;
    if (!f.read(reinterpret_cast<char*>(&count), cs)) return bad(path, "truncated in the faces");
    if (count < 3 || count > 64) return bad(path, "a face with " + std::to_string(count) + " corners");
    std::uint32_t idx[64];
    for (std::uint32_t k = 0; k < count; ++k) {
      idx[k] = 0;
      if (!f.read(reinterpret_cast<char*>(&idx[k]), is)) return bad(path, "truncated in the faces");
      if (idx[k] >= nv) return bad(path, "a face index past the vertices");
    }
    for (std::uint32_t k = 1; k + 1 < count; ++k) m.indices.insert(m.indices.end(), {idx[0], idx[k], idx[k + 1]});
  }
  return m;
}

}  // namespace

std::uint64_t estimate_mesh_bytes(const Mesh& mesh, MeshFormat format) noexcept {
  const std::uint64_t v = mesh.positions.size(), t = mesh.triangles();
  if (format == MeshFormat::ply) return 300 + v * 15 + t * 13;
  const std::uint64_t payload = v * 24 + t * 12;
  // .gltf embeds the buffer as base64 (4 characters per 3 bytes).
  return 1200 + (format == MeshFormat::glb ? payload : (payload + 2) / 3 * 4);
}

Result<std::uint64_t> write_mesh(const Mesh& mesh, MeshFormat format, const std::string& path) {
  const std::string tmp = path + ".part";
  auto r = format == MeshFormat::ply ? write_ply(mesh, tmp)
                                     : write_gltf(mesh, format == MeshFormat::glb, tmp);
  std::error_code ec;
  if (!r) {
    fs::remove(tmp, ec);
    return std::move(r).error();
  }
  fs::rename(tmp, path, ec);
  if (ec) {
    fs::remove(tmp, ec);
    return make_error(Errc::io_error, "writing " + path + ": " + ec.message());
  }
  return static_cast<std::uint64_t>(fs::file_size(path, ec));
}

Result<Mesh> read_mesh_bytes(std::span<const std::uint8_t> bytes, const std::string& format) {
  const std::string what = "the " + format + " file";
  if (format == "ply") return read_ply(bytes, what);
  if (format == "glb") return read_gltf(bytes, what, true);
  if (format == "gltf") return read_gltf(bytes, what, false);
  return make_error(Errc::unsupported, format + ": not gltf, glb or ply");
}

Result<Mesh> read_mesh(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return make_error(Errc::not_found, "no file " + path);
  std::string format;
  if (has_suffix(path, ".ply")) format = "ply";
  if (has_suffix(path, ".glb")) format = "glb";
  if (has_suffix(path, ".gltf")) format = "gltf";
  if (format.empty()) return make_error(Errc::unsupported, path + ": not .gltf, .glb or .ply");
  std::ifstream in(path, std::ios::binary);
  std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)), {});
  if (!in && !in.eof()) return make_error(Errc::io_error, "reading " + path + " failed");
  auto m = read_mesh_bytes(bytes, format);
  if (!m && m.error().code == Errc::malformed)
    return Error{Errc::malformed, path + ": " + m.error().message.substr(m.error().message.find(": ") + 2)};
  return m;
}

}  // namespace deepcanvas::exporting
