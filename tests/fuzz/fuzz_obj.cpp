// Fuzz harness: Wavefront OBJ meshes (io/obj_io.hpp), with and without trimesh's vertex merge.
#include "fuzz_target.hpp"

#include "topos/io/obj_io.hpp"

#include <sstream>

TOPOS_FUZZ_TARGET(obj) {
  using namespace topos_fuzz;
  if (size == 0) return 0;
  // The first byte picks the option, the rest is the file.
  const bool merge = data[0] & 1;
  std::istringstream in(text(data + 1, size - 1));
  try {
    const auto obj = topos::io::parse_obj(in, source(), topos::io::ObjReadOptions().merge(merge));
    const auto& m = obj.mesh;
    check(m.vertices.rows() > 0 && m.faces.rows() > 0, "a mesh read has vertices and faces");
    check(m.faces.minCoeff() >= 0 && m.faces.maxCoeff() < m.vertices.rows(),
          "face indices in range");
    for (std::size_t b = 0; b < obj.blocks.size(); ++b) {
      const auto& blk = obj.blocks[b];
      check(0 <= blk.face_begin && blk.face_begin < blk.face_end && blk.face_end <= m.faces.rows(),
            "blocks are non-empty face ranges");
      const auto part = obj.block_mesh(b);
      check(part.faces.rows() == blk.face_end - blk.face_begin, "a block's mesh has its faces");
    }
  } catch (const topos::MeshError& e) {
    expect_error(e.what());
  }
  return 0;
}
