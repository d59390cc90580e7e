// Tests of topos/core/mesh_lifting.hpp, primitives.hpp and obj_io.hpp: Euler characteristic of
// closed meshes, HOPNet's edge order, boundary of boundary on lifted meshes, OBJ parsing and
// errors.
#include <catch2/catch.hpp>

#include "support/reference.hpp"
#include "topos/core/mesh_lifting.hpp"
#include "topos/io/obj_io.hpp"
#include "topos/mesh/primitives.hpp"

#include <Eigen/Geometry>

#include <filesystem>
#include <sstream>
#include <type_traits>

using namespace topos;

// The OBJ reader's names before io/ had its namespace still name the same types.
static_assert(std::is_same_v<ObjMesh, io::ObjMesh>);

namespace {
std::int64_t euler(const TriangleMesh& m) {
  auto l = lift_meshes({m});
  return l.complex.size(0) - l.complex.size(1) + l.complex.size(2);
}
void check_closed_oriented(const TriangleMesh& m) {
  auto l = lift_meshes({m});
  const Eigen::MatrixXd B1 = l.complex.signed_incidence_matrix(0, 1),
                        B2 = l.complex.signed_incidence_matrix(1, 2);
  REQUIRE((B1 * B2).cwiseAbs().maxCoeff() == 0.0);
  // Closed and consistently oriented: every edge has two faces with opposite signs.
  REQUIRE(B2.cwiseAbs().rowwise().sum().minCoeff() == 2.0);
  REQUIRE(B2.rowwise().sum().cwiseAbs().maxCoeff() == 0.0);
}
}  // namespace

TEST_CASE("built-in shapes are closed oriented spheres of 50-70 nodes",
          "[core][lifting][primitives]") {
  for (const std::string name : {"sphere", "cube", "cylinder"}) {
    INFO(name);
    const TriangleMesh m = builtin_shape(name);
    REQUIRE(m.num_vertices() >= 50);
    REQUIRE(m.num_vertices() <= 70);
    REQUIRE(euler(m) == 2);
    check_closed_oriented(m);
    // Outward orientation: positive signed volume.
    double vol = 0;
    for (Eigen::Index f = 0; f < m.faces.rows(); ++f)
      vol += m.vertices.row(m.faces(f, 0))
                 .dot(m.vertices.row(m.faces(f, 1)).cross(m.vertices.row(m.faces(f, 2)))) /
             6;
    REQUIRE(vol > 0);
  }
  REQUIRE(uv_sphere(8, 8).num_vertices() == 58);
  REQUIRE(box_mesh(3).num_vertices() == 56);
  REQUIRE(cylinder_mesh(20, 3).num_vertices() == 62);
  REQUIRE_THROWS_AS(builtin_shape("teapot"), MeshError);
}

TEST_CASE("lifting several objects follows the documented order", "[core][lifting]") {
  TriangleMesh a = box_mesh(1), b = uv_sphere(4, 5);
  auto l = lift_meshes({a, b}, LiftOptions().with_faces(false).with_object_rank(4));
  REQUIRE(l.complex.size(0) == a.num_vertices() + b.num_vertices());
  REQUIRE(l.complex.size(2) == 0);
  REQUIRE(l.complex.size(4) == 2);
  REQUIRE(l.node_offset == std::vector<std::int64_t>{0, 8, 8 + b.num_vertices()});
  // First edges are the first face's directed pairs, in order.
  const auto f0 = a.faces.row(0);
  REQUIRE(l.edges[0] == std::array<std::int64_t, 2>{f0(0), f0(1)});
  REQUIRE(l.edges[1] == std::array<std::int64_t, 2>{f0(1), f0(2)});
  REQUIRE(l.edges[2] == std::array<std::int64_t, 2>{f0(2), f0(0)});
  REQUIRE(l.complex.oriented_nodes(1, 1) == std::vector<std::int64_t>{f0(1), f0(2)});
  // Second object's edges use global ids.
  const auto e = l.edges[static_cast<std::size_t>(l.complex.size(1)) - 1];
  REQUIRE(e[0] >= 8);
  REQUIRE(l.complex.cell_nodes(4, 1).front() == 8);
  // B04 is node membership.
  const Eigen::MatrixXd B04 = l.complex.incidence_matrix(0, 4);
  REQUIRE(B04.col(0).sum() == 8);
  REQUIRE(B04.col(1).sum() == b.num_vertices());
  // Per-frame faces on top of the static part.
  const auto mark = l.complex.mark();
  l.complex.add_cell({0, 1, 2}, 2);
  REQUIRE(l.complex.incidence_matrix(2, 4).coeff(0, 0) == 1.0);
  l.complex.rollback(mark);
  REQUIRE(l.complex.size(2) == 0);
}

TEST_CASE("lifting rejects broken meshes with clear errors", "[core][lifting][errors]") {
  TriangleMesh m = box_mesh(1);
  m.name = "box";
  TriangleMesh bad = m;
  bad.faces(3, 1) = 99;
  REQUIRE_THROWS_WITH(lift_meshes({bad}), Catch::Contains("mesh 'box': face 3 uses vertex 99"));
  bad = m;
  bad.vertices(2, 0) = std::nan("");
  REQUIRE_THROWS_WITH(lift_meshes({bad}), Catch::Contains("vertex 2 has a non-finite coordinate"));
  bad = m;
  bad.faces.row(5) = bad.faces.row(4).reverse();
  REQUIRE_THROWS_WITH(lift_meshes({bad}),
                      Catch::Contains("face 5 of object 0 duplicates an earlier face"));
  REQUIRE_THROWS_WITH(lift_meshes({TriangleMesh{}}), Catch::Contains("is empty"));
  TriangleMesh tri;
  tri.vertices = TriangleMesh::Vertices::Identity(3, 3);
  tri.faces.resize(1, 3);
  tri.faces << 0, 1, 2;
  REQUIRE_THROWS_WITH(lift_meshes({tri}), Catch::Contains("already exists at rank 2"));
}

TEST_CASE("OBJ parsing: blocks, v/vt/vn triples, negative indices, trimesh merge", "[core][obj]") {
  std::istringstream in(
      "# comment\nmtllib x.mtl\no first\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n"
      "f 1/1/1 2/1/1 3/1/1\no second\nv 0 0 0\nv 0 0 1\nf -4 -2 -1\n");
  auto obj = io::parse_obj(in, "mem.obj");
  REQUIRE(obj.mesh.num_vertices() == 5);
  REQUIRE(obj.blocks.size() == 2);
  REQUIRE(obj.blocks[1].name == "second");
  REQUIRE(obj.mesh.faces(1, 0) == 1);
  REQUIRE(obj.block_mesh(1).num_vertices() == 3);
  std::istringstream in2(in.str());
  in.clear();
  std::istringstream again(
      "o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\no b\nv 0 0 0\nv 0 0 1\nf 4 2 5\n");
  auto merged = io::parse_obj(again, "mem.obj", io::ObjReadOptions().merge(true));
  REQUIRE(merged.mesh.num_vertices() == 4);
  REQUIRE(merged.mesh.faces(1, 0) == 0);
}

TEST_CASE("OBJ errors name the file and line", "[core][obj][errors]") {
  auto err = [](const std::string& text) {
    std::istringstream in(text);
    try {
      io::parse_obj(in, "bad.obj");
    } catch (const MeshError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  CHECK(err("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3 4\n") ==
        "bad.obj:5: face with 4 vertices; only triangles are supported");
  CHECK(err("v 0 0 0\nv 1 0 nan\n") == "bad.obj:2: non-finite coordinate 'nan'");
  CHECK(err("v 0 0 0\nv 1 0 x\n") == "bad.obj:2: bad coordinate 'x'");
  CHECK(err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n") ==
        "bad.obj:4: face index 7 out of range (3 vertices so far)");
  CHECK(err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 2\n") == "bad.obj:4: face repeats a vertex");
  CHECK(err("v 0 0\n") == "bad.obj:1: vertex needs 3 coordinates");
  CHECK(err("") == "bad.obj: no vertices");
  CHECK_THROWS_WITH(io::read_obj("/nonexistent/x.obj"), "/nonexistent/x.obj: cannot open file");
}

TEST_CASE("every convex part of the KuBasic meshes has V - E + F = 2",
          "[core][lifting][reference]") {
  const auto dir = test::reference_dir("KuBasic Euler characteristic") / "data" / "kubasic";
  int parts = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    const auto path = entry.path() / "collision_geometry.obj";
    // The floor dome is an open quad surface, not a closed convex part.
    if (!std::filesystem::exists(path) || entry.path().filename() == "dome") continue;
    const io::ObjMesh obj = io::read_obj(path.string());
    for (std::size_t b = 0; b < obj.blocks.size(); ++b) {
      const TriangleMesh part = obj.block_mesh(b);
      INFO(path.string() << " block " << obj.blocks[b].name);
      CHECK(euler(part) == 2);
      ++parts;
    }
  }
  REQUIRE(parts >= 180);
}

TEST_CASE("trimesh's duplicate merge gives the reference's vertex counts",
          "[core][obj][reference]") {
  const auto dir = test::reference_dir("KuBasic merged vertex counts") / "data" / "kubasic";
  const std::vector<std::pair<std::string, std::int64_t>> expected = {
      {"cube", 51},     {"sphere", 64}, {"cylinder", 64},    {"cone", 64},
      {"teapot", 274},  {"gear", 565},  {"sponge", 791},     {"spot", 681},
      {"suzanne", 521}, {"torus", 639}, {"torus_knot", 1141}};
  for (auto& [shape, n] : expected) {
    INFO(shape);
    const auto obj = io::read_obj((dir / shape / "collision_geometry.obj").string(),
                                  io::ObjReadOptions().merge(true));
    CHECK(obj.mesh.num_vertices() == n);
  }
}
