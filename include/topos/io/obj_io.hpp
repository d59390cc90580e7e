// topos/io/obj_io.hpp
// Reading Wavefront OBJ triangle meshes: `v`, `f` (1-based or negative indices; only the first
// index of each v/vt/vn triple is used), and `o` blocks (KuBasic collision meshes keep one convex
// part per block). Optionally merges exact duplicate vertices the way trimesh does when loading
// (key = round(v * 1e8) as int64, first occurrence kept in order, faces re-indexed, unreferenced
// vertices dropped). Errors name the file and line. Std + Eigen only.
#pragma once

#include "topos/mesh/triangle_mesh.hpp"

#include <algorithm>
#include <array>
#include <cstdlib>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace topos::io {

struct ObjBlock {
  std::string name;
  std::int64_t face_begin = 0, face_end = 0;  ///< face range of this block in the mesh
};

struct ObjMesh {
  TriangleMesh mesh;
  std::vector<ObjBlock> blocks;  ///< `o` blocks in file order (one unnamed block if none)

  /// The faces of block b as a mesh of its own (only the vertices it references, in order).
  TriangleMesh block_mesh(std::size_t b) const {
    const ObjBlock& blk = blocks.at(b);
    std::map<std::int64_t, std::int64_t> local;
    for (std::int64_t f = blk.face_begin; f < blk.face_end; ++f)
      for (int k = 0; k < 3; ++k) local.emplace(mesh.faces(f, k), 0);
    TriangleMesh out;
    out.name = mesh.name + ":" + blk.name;
    out.vertices.resize(static_cast<Eigen::Index>(local.size()), 3);
    std::int64_t i = 0;
    for (auto& [g, l] : local) {
      l = i;
      out.vertices.row(i++) = mesh.vertices.row(g);
    }
    out.faces.resize(blk.face_end - blk.face_begin, 3);
    for (std::int64_t f = blk.face_begin; f < blk.face_end; ++f)
      for (int k = 0; k < 3; ++k) out.faces(f - blk.face_begin, k) = local[mesh.faces(f, k)];
    return out;
  }
};

struct ObjReadOptions {
  bool merge_duplicate_vertices = false;  ///< trimesh's default processing (the reference's meshes)
  ObjReadOptions& merge(bool v) {
    merge_duplicate_vertices = v;
    return *this;
  }
};

/// Merges exact duplicate vertices as trimesh does (round(v * 1e8)), dropping unreferenced ones.
inline void merge_duplicate_vertices(TriangleMesh& m) {
  std::map<std::array<std::int64_t, 3>, std::int64_t> first;
  std::vector<std::int64_t> remap(static_cast<std::size_t>(m.vertices.rows()));
  std::vector<std::int64_t> keep;
  for (Eigen::Index v = 0; v < m.vertices.rows(); ++v) {
    std::array<std::int64_t, 3> key;
    for (int k = 0; k < 3; ++k)
      key[static_cast<std::size_t>(k)] =
          static_cast<std::int64_t>(std::llround(m.vertices(v, k) * 1e8));
    auto [it, fresh] = first.emplace(key, static_cast<std::int64_t>(keep.size()));
    if (fresh) keep.push_back(v);
    remap[static_cast<std::size_t>(v)] = it->second;
  }
  // Drop vertices no face references (renumbering in order).
  std::vector<char> used(keep.size(), 0);
  for (Eigen::Index f = 0; f < m.faces.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      used[static_cast<std::size_t>(remap[static_cast<std::size_t>(m.faces(f, k))])] = 1;
  std::vector<std::int64_t> final_id(keep.size(), -1);
  TriangleMesh::Vertices nv(static_cast<Eigen::Index>(keep.size()), 3);
  std::int64_t n = 0;
  for (std::size_t i = 0; i < keep.size(); ++i) {
    if (!used[i]) continue;
    final_id[i] = n;
    nv.row(n++) = m.vertices.row(keep[i]);
  }
  nv.conservativeResize(n, 3);
  for (Eigen::Index f = 0; f < m.faces.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      m.faces(f, k) =
          final_id[static_cast<std::size_t>(remap[static_cast<std::size_t>(m.faces(f, k))])];
  m.vertices = std::move(nv);
}

/// Parses OBJ text; `source` names it in errors.
inline ObjMesh parse_obj(std::istream& in, const std::string& source,
                         const ObjReadOptions& opt = {}) {
  std::vector<double> v;
  std::vector<std::int64_t> f;
  ObjMesh out;
  std::string line;
  std::int64_t lineno = 0;
  const auto fail = [&](const std::string& why) {
    throw MeshError(source + ":" + std::to_string(lineno) + ": " + why);
  };
  while (std::getline(in, line)) {
    ++lineno;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string tag;
    if (!(ls >> tag) || tag[0] == '#') continue;
    if (tag == "v") {
      double x[3];
      for (double& c : x) {
        std::string tok;
        if (!(ls >> tok)) fail("vertex needs 3 coordinates");
        char* end = nullptr;
        c = std::strtod(tok.c_str(), &end);
        if (end == tok.c_str() || *end != '\0') fail("bad coordinate '" + tok + "'");
        if (!std::isfinite(c)) fail("non-finite coordinate '" + tok + "'");
      }
      v.insert(v.end(), x, x + 3);
    } else if (tag == "f") {
      std::vector<std::int64_t> idx;
      std::string tok;
      while (ls >> tok) {
        const std::string first = tok.substr(0, tok.find('/'));
        char* end = nullptr;
        const long long i = std::strtoll(first.c_str(), &end, 10);
        if (first.empty() || *end != '\0' || i == 0) fail("bad face index '" + tok + "'");
        const std::int64_t nverts = static_cast<std::int64_t>(v.size() / 3);
        const std::int64_t zero_based = i > 0 ? i - 1 : nverts + i;
        if (zero_based < 0 || zero_based >= nverts)
          fail("face index " + std::to_string(i) + " out of range (" + std::to_string(nverts) +
               " vertices so far)");
        idx.push_back(zero_based);
      }
      if (idx.size() != 3)
        fail("face with " + std::to_string(idx.size()) + " vertices; only triangles are supported");
      if (idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2]) fail("face repeats a vertex");
      if (out.blocks.empty()) out.blocks.push_back({"", 0, 0});
      f.insert(f.end(), idx.begin(), idx.end());
      out.blocks.back().face_end = static_cast<std::int64_t>(f.size() / 3);
    } else if (tag == "o" || tag == "g") {
      if (tag == "g" && !out.blocks.empty() &&
          out.blocks.back().face_end == out.blocks.back().face_begin)
        continue;
      std::string name;
      std::getline(ls >> std::ws, name);
      const std::int64_t at = static_cast<std::int64_t>(f.size() / 3);
      if (!out.blocks.empty() && out.blocks.back().face_end == at &&
          out.blocks.back().face_begin == at) {
        out.blocks.back().name = name;  // an empty block is renamed rather than kept
      } else {
        out.blocks.push_back({name, at, at});
      }
    }
    // vt, vn, s, usemtl, mtllib and others carry nothing the meshes need.
  }
  if (in.bad()) throw MeshError(source + ": read error");
  if (v.empty() || f.empty())
    throw MeshError(source + ": no " + std::string(v.empty() ? "vertices" : "faces"));
  out.blocks.erase(std::remove_if(out.blocks.begin(), out.blocks.end(),
                                  [](const ObjBlock& b) { return b.face_begin == b.face_end; }),
                   out.blocks.end());
  out.mesh.name = source;
  out.mesh.vertices =
      Eigen::Map<TriangleMesh::Vertices>(v.data(), static_cast<Eigen::Index>(v.size() / 3), 3);
  out.mesh.faces =
      Eigen::Map<TriangleMesh::Faces>(f.data(), static_cast<Eigen::Index>(f.size() / 3), 3);
  if (opt.merge_duplicate_vertices) merge_duplicate_vertices(out.mesh);
  out.mesh.validate();
  return out;
}

/// Reads an OBJ file; throws MeshError naming the file (and line) on any problem.
inline ObjMesh read_obj(const std::string& path, const ObjReadOptions& opt = {}) {
  std::ifstream in(path);
  if (!in) throw MeshError(path + ": cannot open file");
  return parse_obj(in, path, opt);
}

}  // namespace topos::io

namespace topos {
// Deprecated: the old flat names. Write io::read_obj (etc.).
using io::merge_duplicate_vertices;
using io::ObjBlock;
using io::ObjMesh;
using io::ObjReadOptions;
using io::parse_obj;
using io::read_obj;
}  // namespace topos
