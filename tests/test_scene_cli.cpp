// The dvisim command-line program, scenes and the Bullet bridge, checked from outside: the CLI binary
// is run on good and bad inputs (exit codes, one-line errors, outputs), .bullet files are written by
// Bullet's own serializer here and read back, and imported shapes are compared with Bullet's support
// functions (answers the importer did not produce).
#include <btBulletDynamicsCommon.h>
#include <BulletCollision/CollisionShapes/btMultiSphereShape.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/collision/narrowphase.h"
#include "chrono_like/io/scene.h"
#include "cli_test_util.h"
#include "stock_bullet_world.h"

using namespace dvi;
namespace fs = std::filesystem;

namespace {

using namespace clitest;  // runCli, tempDir, slurp, spit, quote, expectInputError (cli_test_util.h)

const char* kTinyScene = R"({
  "name": "tiny",
  "settings": { "dt": 0.001, "steps": 4 },
  "bodies": [
    { "name": "ground", "shape": { "type": "plane", "normal": [0, 1, 0] }, "mass": 0 },
    { "name": "a", "shape": { "type": "sphere", "radius": 0.1 }, "mass": 1, "position": [0, 0.099, 0] },
    { "name": "b", "shape": { "type": "box", "half_extents": [0.1, 0.1, 0.1] }, "mass": 2, "position": [0.5, 0.3, 0],
      "rotation": { "axis": [0, 1, 0], "angle_deg": 30 }, "velocity": [1, 0, 0] }
  ]
})";

// ------------------------------------------------------------------------------------------------
// Every supported Bullet shape, in a world, serialized by Bullet itself.
// ------------------------------------------------------------------------------------------------
struct BulletWorldFixture : StockBulletWorld {
  std::vector<btRigidBody*> ptrs;

  BulletWorldFixture() {
    add(keep(new btStaticPlaneShape(btVector3(0, 1, 0), 0)), 0, btVector3(0, 0, 0));
    add(keep(new btSphereShape(0.1f)), 1, btVector3(0, 1, 0));
    add(keep(new btBoxShape(btVector3(0.1f, 0.2f, 0.3f))), 2, btVector3(1, 1, 0),
        btQuaternion(btVector3(0, 0, 1), 0.3f));
    add(keep(new btCylinderShape(btVector3(0.1f, 0.3f, 0.1f))), 1, btVector3(2, 1, 0));
    add(keep(new btCylinderShapeX(btVector3(0.3f, 0.1f, 0.1f))), 1, btVector3(3, 1, 0));
    add(keep(new btCylinderShapeZ(btVector3(0.1f, 0.1f, 0.3f))), 1, btVector3(4, 1, 0));
    add(keep(new btCapsuleShape(0.1f, 0.4f)), 1, btVector3(5, 1, 0));
    add(keep(new btCapsuleShapeX(0.1f, 0.4f)), 1, btVector3(6, 1, 0));
    add(keep(new btCapsuleShapeZ(0.1f, 0.4f)), 1, btVector3(6.5f, 1, 0));
    add(keep(new btConeShape(0.2f, 0.4f)), 1, btVector3(7, 1, 0));
    add(keep(new btConeShapeX(0.2f, 0.4f)), 1, btVector3(8, 1, 0));
    add(keep(new btConeShapeZ(0.2f, 0.4f)), 1, btVector3(9, 1, 0));
    {
      const btScalar pts[] = {0.1f, 0.1f, 0.1f, -0.1f, -0.1f, 0.1f, -0.1f, 0.1f, -0.1f, 0.1f, -0.1f, -0.1f};
      auto* hull = new btConvexHullShape(pts, 4, 3 * sizeof(btScalar));
      hull->setLocalScaling(btVector3(1, 2, 1));
      add(keep(hull), 1, btVector3(10, 1, 0));
    }
    {
      const btVector3 pos[] = {btVector3(-0.1f, 0, 0), btVector3(0.1f, 0, 0)};
      const btScalar rad[] = {0.1f, 0.15f};
      add(keep(new btMultiSphereShape(pos, rad, 2)), 1, btVector3(11, 1, 0));
    }
    {
      const btVector3 pos(0, 0, 0);
      const btScalar rad = 1;
      auto* ell = new btMultiSphereShape(&pos, &rad, 1);
      ell->setLocalScaling(btVector3(0.3f, 0.2f, 0.1f));
      add(keep(ell), 1, btVector3(12, 1, 0));
    }
    {
      auto* comp = new btCompoundShape();
      comp->addChildShape(btTransform(btQuaternion::getIdentity(), btVector3(0.2f, 0, 0)),
                          keep(new btSphereShape(0.1f)));
      comp->addChildShape(btTransform(btQuaternion(btVector3(0, 1, 0), 0.5f), btVector3(-0.2f, 0, 0)),
                          keep(new btBoxShape(btVector3(0.1f, 0.05f, 0.1f))));
      comp->addChildShape(btTransform(btQuaternion::getIdentity(), btVector3(0, 0.2f, 0)),
                          keep(new btCylinderShapeX(btVector3(0.1f, 0.05f, 0.05f))));
      add(keep(comp), 1, btVector3(13, 1, 0));
    }
    ptrs.back()->setLinearVelocity(btVector3(0.5f, 1.5f, -0.25f));
    ptrs.back()->setAngularVelocity(btVector3(0, 2, 0));
    // A kinematic paddle and a body with its own gravity.
    add(keep(new btBoxShape(btVector3(0.05f, 0.2f, 0.5f))), 0, btVector3(-2, 0.2f, 0));
    ptrs.back()->setCollisionFlags(ptrs.back()->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
    ptrs.back()->setActivationState(DISABLE_DEACTIVATION);
    ptrs.back()->setLinearVelocity(btVector3(0.3f, 0, 0));
    add(keep(new btSphereShape(0.1f)), 1, btVector3(-3, 1, 0));
    ptrs.back()->setGravity(btVector3(0, -1, 0));
    // Bodies of mass other than 1, with the world's gravity and with their own: Bullet serialises the gravity
    // force m g beside the acceleration g, and only the acceleration is a body's gravity.
    add(keep(new btSphereShape(0.1f)), 7.5f, btVector3(-4, 1, 0));
    add(keep(new btSphereShape(0.1f)), 1000, btVector3(-5, 1, 0));
    ptrs.back()->setGravity(btVector3(0, -2, 0));
  }
  void add(btCollisionShape* s, btScalar mass, const btVector3& pos,
           const btQuaternion& rot = btQuaternion::getIdentity()) {
    ptrs.push_back(addBody(s, mass, pos, rot));
    ptrs.back()->setFriction(0.6f);
  }
  void save(const fs::path& p) {
    btDefaultSerializer ser;
    world.serialize(&ser);
    std::ofstream f(p, std::ios::binary);
    f.write(reinterpret_cast<const char*>(ser.getBufferPointer()), ser.getCurrentBufferSize());
  }
};

// Support value h(d) = max over the shape of x.d, for a record at its local pose (margin excluded).
real supportValue(const ShapeDesc& s, Vec3 d) {
  const Vec3 dl = rotateInv(s.shape.local.q, d);
  const Vec3 x = supportLocal(s.shape, dl, s.hull.data());
  return dot(transformPoint(s.shape.local, x), d);
}

// The same from Bullet's own support function.
real bulletSupport(const btConvexShape& s, Vec3 d, bool with_margin) {
  const btVector3 bd(btScalar(d.x), btScalar(d.y), btScalar(d.z));
  const btVector3 v = with_margin ? s.localGetSupportingVertex(bd) : s.localGetSupportingVertexWithoutMargin(bd);
  return real(v.dot(bd));
}

std::vector<Vec3> probeDirections() {
  std::vector<Vec3> d;
  for (int x = -1; x <= 1; ++x)
    for (int y = -1; y <= 1; ++y)
      for (int z = -1; z <= 1; ++z)
        if (x || y || z) d.push_back(normalized(Vec3{real(x), real(y), real(z)}));
  return d;
}

}  // namespace

// ------------------------------------------------------------------------------------------------
// Bad input: exit code 2 and one line naming the problem, never a crash.
// ------------------------------------------------------------------------------------------------
TEST_CASE("CLI: bad scene files are refused with one line and exit code 2", "[cli]") {
  const fs::path d = tempDir("bad");
  const std::string dir = d.string();

  spit(d / "malformed.json", "{ \"bodies\": [ { \"shape\": ");
  expectInputError("run " + quote(dir + "/malformed.json") + " --steps 1 --out " + quote(dir + "/o"), "malformed JSON");

  spit(d / "empty.json", "");
  expectInputError("run " + quote(dir + "/empty.json") + " --out " + quote(dir + "/o"), "empty");

  spit(d / "empty.bullet", "");
  expectInputError("run " + quote(dir + "/empty.bullet") + " --out " + quote(dir + "/o"), "empty");

  spit(d / "foreign.bullet", std::string("PK\x03\x04 this is a zip file, not Bullet at all..."));
  expectInputError("run " + quote(dir + "/foreign.bullet") + " --out " + quote(dir + "/o"), "not a .bullet file");

  {
    BulletWorldFixture w;
    w.save(d / "good.bullet");
    const std::string good = slurp(d / "good.bullet");
    REQUIRE(good.size() > 1000);
    spit(d / "truncated.bullet", good.substr(0, good.size() / 2));
    expectInputError("run " + quote(dir + "/truncated.bullet") + " --out " + quote(dir + "/o"), "truncated");
    spit(d / "header_only.bullet", good.substr(0, 12));
    expectInputError("run " + quote(dir + "/header_only.bullet") + " --out " + quote(dir + "/o"), "truncated");
    std::string garbled = good;
    for (size_t i = 12; i < garbled.size(); i += 7) garbled[i] = char(0xA5);
    spit(d / "garbled.bullet", garbled);
    expectInputError("run " + quote(dir + "/garbled.bullet") + " --out " + quote(dir + "/o"), ".bullet");
  }

  expectInputError("run " + quote(dir + "/does_not_exist.json") + " --out " + quote(dir + "/o"), "no such file");
  expectInputError("run " + quote(dir + "/does_not_exist.bullet") + " --out " + quote(dir + "/o"), "no such file");
  spit(d / "scene.txt", "{}");
  expectInputError("run " + quote(dir + "/scene.txt") + " --out " + quote(dir + "/o"), "extension");
  fs::remove_all(d);
}

TEST_CASE("CLI: bad values in a JSON scene name the key path", "[cli]") {
  const fs::path d = tempDir("values");
  const std::string dir = d.string();
  auto scene = [&](const std::string& name, const std::string& body) {
    spit(
        d / name,
        R"({ "settings": { "steps": 2 }, "bodies": [ { "shape": { "type": "plane", "normal": [0, 1, 0] }, "mass": 0 }, )" +
            body + " ] }");
    return quote(dir + "/" + name) + " --out " + quote(dir + "/o");
  };
  expectInputError("run " + scene("nan_string.json",
                                  R"({ "shape": { "type": "sphere", "radius": 0.1 }, "position": [0, "nan", 0] })"),
                   "bodies[1].position[1]");
  expectInputError(
      "run " + scene("nan_huge.json", R"({ "shape": { "type": "sphere", "radius": 0.1 }, "position": [0, 1e999, 0] })"),
      "1e999");
  expectInputError("run " + scene("neg_mass.json", R"({ "shape": { "type": "sphere", "radius": 0.1 }, "mass": -1 })"),
                   "bodies[1].mass");
  expectInputError("run " + scene("zero_radius.json", R"({ "shape": { "type": "sphere", "radius": 0 } })"),
                   "bodies[1].shape.radius");
  expectInputError(
      "run " + scene("neg_box.json", R"({ "shape": { "type": "box", "half_extents": [0.1, -0.1, 0.1] } })"),
      "half_extents[1]");
  expectInputError(
      "run " + scene("unknown_key.json", R"({ "shape": { "type": "sphere", "radius": 0.1 }, "colour": "red" })"),
      "bodies[1].colour");
  expectInputError(
      "run " + scene("unknown_shape_key.json", R"({ "shape": { "type": "sphere", "radius": 0.1, "height": 2 } })"),
      "bodies[1].shape.height");
  expectInputError("run " + scene("unknown_type.json", R"({ "shape": { "type": "torus", "radius": 0.1 } })"), "torus");
  expectInputError("run " + scene("wrong_type.json", R"({ "shape": { "type": "sphere", "radius": "big" } })"),
                   "bodies[1].shape.radius");
  expectInputError(
      "run " + scene("dyn_plane.json", R"({ "shape": { "type": "plane", "normal": [0, 1, 0] }, "mass": 1 })"), "plane");
  expectInputError(
      "run " + scene("flat_hull.json",
                     R"({ "shape": { "type": "convex_hull", "points": [[0,0,0],[1,0,0],[0,1,0],[1,1,0]] } })"),
      "coplanar");
  spit(
      d / "bad_setting.json",
      R"({ "settings": { "dt": 0.001, "stepz": 3 }, "bodies": [ { "shape": { "type": "sphere", "radius": 0.1 } } ] })");
  expectInputError("run " + quote(dir + "/bad_setting.json") + " --out " + quote(dir + "/o"), "settings.stepz");
  fs::remove_all(d);
}

TEST_CASE("CLI: bad command lines get exit code 2", "[cli]") {
  const fs::path d = tempDir("args");
  const std::string dir = d.string();
  spit(d / "tiny.json", kTinyScene);
  const std::string s = quote(dir + "/tiny.json") + " --out " + quote(dir + "/o");
  expectInputError("run " + s + " --dt -1", "--dt");
  expectInputError("run " + s + " --dt 0", "--dt");
  expectInputError("run " + s + " --dt nan", "--dt");
  expectInputError("run " + s + " --backend warp", "backend");
  expectInputError("run " + s + " --solver newton", "solver");
  expectInputError("run " + s + " --collision fcl", "collision");
  expectInputError("run " + s + " --time 1 --steps 10", "--steps");
  expectInputError("run " + s + " --steps -3", "--steps");
  expectInputError("run " + s + " --set settings.nope=1", "settings.nope");
  expectInputError("run " + s + " --set settings.dt=-1", "settings.dt");
  expectInputError("run " + s + " --set bodies.7.mass=1", "bodies.7.mass");
  expectInputError("run " + s + " --set bodies.1.mass=-2", "bodies[1].mass");
  expectInputError("run " + s + " --set novalue", "KEY=VALUE");
  expectInputError("run " + s + " --frobnicate", "frobnicate");
  // Without a GPU build or device, an explicit GPU request is refused (with one, it would run).
  {
    const CliResult r = runCli("run " + s + " --backend gpu --steps 1");
    CHECK((r.code == 0 || (r.code == 2 && r.errLines() == 1)));
  }
  fs::remove_all(d);
}

// ------------------------------------------------------------------------------------------------
// Good runs and their outputs
// ------------------------------------------------------------------------------------------------
TEST_CASE("CLI: a JSON scene round trip writes summary.json, bodies.csv and frames", "[cli]") {
  const fs::path d = tempDir("roundtrip");
  spit(d / "tiny.json", kTinyScene);
  const fs::path out = d / "out";
  const CliResult r = runCli("run " + quote((d / "tiny.json").string()) +
                             " --backend cpu --frames 3 --set settings.dt=0.002 --out " + quote(out.string()));
  INFO(r.out << r.err);
  REQUIRE(r.code == 0);
  CHECK(r.err.empty());
  CHECK(r.out.find(out.string()) != std::string::npos);  // says where the results went

  // bodies.csv: exact header, one row per body in scene order, 14 columns.
  std::istringstream csv(slurp(out / "bodies.csv"));
  std::string line;
  std::getline(csv, line);
  CHECK(line == "id,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz");
  int rows = 0;
  while (std::getline(csv, line)) {
    int commas = 0;
    for (char c : line) commas += c == ',';
    CHECK(commas == 13);
    CHECK(line.rfind(std::to_string(rows) + ",", 0) == 0);
    ++rows;
  }
  CHECK(rows == 3);

  const auto j = nlohmann::json::parse(slurp(out / "summary.json"));
  for (const char* k : {"backend", "device", "solver", "dt", "steps", "sim_time", "wall_time_s", "bodies",
                        "contacts_mean", "max_penetration", "iterations_mean", "residual_final", "stages",
                        "stage_seconds", "threads", "collision", "scene"})
    CHECK(j.contains(k));
  CHECK(j["backend"] == "cpu");
  CHECK(j["bodies"] == 3);
  CHECK(j["steps"] == 4);
  CHECK(j["dt"].get<double>() == Approx(0.002));
  CHECK(j["stages"].is_array());
  CHECK(!j["stages"].empty());
  CHECK(j["frames"] == 3);
  CHECK(fs::exists(out / "frame_0000.vtp"));
  CHECK(fs::exists(out / "frame_0002.vtp"));
  const std::string pvd = slurp(out / "frames.pvd");
  CHECK(pvd.find("frame_0002.vtp") != std::string::npos);
  const std::string vtp = slurp(out / "frame_0001.vtp");
  CHECK(vtp.find("NumberOfPoints=\"3\"") != std::string::npos);
  CHECK(vtp.find("Name=\"velocity\"") != std::string::npos);
  CHECK(vtp.find("Name=\"orientation\"") != std::string::npos);
  // No temporary files left behind.
  for (const auto& e : fs::directory_iterator(out)) CHECK(e.path().string().find(".tmp.") == std::string::npos);
  fs::remove_all(d);
}

TEST_CASE("Scenes: the shipped examples and the embedded default load", "[cli]") {
  for (const char* name : {"pile.json", "stack.json", "incline.json", "mixed_shapes.json"}) {
    INFO(name);
    Scene s = Scene::load(std::string(DVISIM_SOURCE_DIR) + "/scenes/" + name);
    CHECK(s.bodyCount() > 0);
    for (btRigidBody* b : s.bodies()) CHECK_NOTHROW(bodyDescFromBullet(*b));
  }
  Scene def = Scene::load("");
  CHECK(def.bodyCount() > 1000);
  // Generators are deterministic: the same scene twice gives the same bodies.
  Scene again = Scene::load("");
  REQUIRE(again.bodyCount() == def.bodyCount());
  for (size_t i = 0; i < def.bodyCount(); i += 97)
    CHECK(def.bodies()[i]->getCenterOfMassPosition() == again.bodies()[i]->getCenterOfMassPosition());
  // Overrides reach into generators.
  Scene small = Scene::load("", {"bodies.5.generator.count=10", "settings.steps=3"});
  CHECK(small.bodyCount() == 15);
  CHECK(small.settings.stepCount() == 3);
  // The stack's boxes touch face to face: grid spacing equal to the box size is allowed.
  Scene stack = Scene::load(std::string(DVISIM_SOURCE_DIR) + "/scenes/stack.json");
  CHECK(stack.bodyCount() == 11);
}

TEST_CASE("CLI: runs the embedded default and the example scenes briefly", "[cli]") {
  const fs::path d = tempDir("default");
  // the embedded default is the CES machine: a few steps of it (its own outputs are tested in
  // test_ces_machine.cpp)
  CliResult r = runCli("run --steps 3 --out " + quote((d / "def").string()));
  INFO(r.out << r.err);
  CHECK(r.code == 0);
  CHECK(fs::exists(d / "def" / "summary.json"));
  r = runCli("run " + quote(std::string(DVISIM_SOURCE_DIR) + "/scenes/pile.json") +
             " --steps 2 --set bodies.5.generator.count=50 --out " + quote((d / "pile").string()));
  INFO(r.out << r.err);
  CHECK(r.code == 0);
  CHECK(fs::exists(d / "pile" / "summary.json"));
  r = runCli("run " + quote(std::string(DVISIM_SOURCE_DIR) + "/scenes/mixed_shapes.json") + " --steps 3 --out " +
             quote((d / "mixed").string()));
  CHECK(r.code == 0);
  fs::remove_all(d);
}

// ------------------------------------------------------------------------------------------------
// The Bullet bridge
// ------------------------------------------------------------------------------------------------
TEST_CASE("Bullet import: box half extents and shape dimensions match Bullet's", "[cli][bullet]") {
  btBoxShape box(btVector3(0.1f, 0.2f, 0.3f));
  std::vector<ShapeDesc> out;
  appendShapesFromBullet(box, Pose{{0, 0, 0}, {1, 0, 0, 0}}, out);
  REQUIRE(out.size() == 1);
  CHECK(out[0].shape.type == ShapeType::Box);
  const btVector3 he = box.getHalfExtentsWithMargin();
  CHECK(out[0].shape.dims.x == Approx(he.x()));
  CHECK(out[0].shape.dims.y == Approx(he.y()));
  CHECK(out[0].shape.dims.z == Approx(he.z()));
  CHECK(out[0].shape.size == Approx(0.1));
  CHECK(out[0].shape.group == 1);
  CHECK(out[0].shape.mask == -1);

  btTriangleMesh mesh;
  mesh.addTriangle(btVector3(0, 0, 0), btVector3(1, 0, 0), btVector3(0, 1, 0));
  btBvhTriangleMeshShape tri(&mesh, true);
  std::vector<ShapeDesc> none;
  CHECK_THROWS_AS(appendShapesFromBullet(tri, Pose{{0, 0, 0}, {1, 0, 0, 0}}, none), InputError);
}

TEST_CASE("Bullet import: X/Y/Z variants are rotated onto Bullet's axes (support functions agree)", "[cli][bullet]") {
  const Pose id{{0, 0, 0}, {1, 0, 0, 0}};
  // Cylinders: compare along the axes (Bullet rounds the rims by the margin, so diagonals differ), and
  // an independent closed form of the canonical cylinder.
  btCylinderShape cy(btVector3(0.1f, 0.3f, 0.1f));
  btCylinderShapeX cx(btVector3(0.3f, 0.1f, 0.1f));
  btCylinderShapeZ cz(btVector3(0.1f, 0.1f, 0.3f));
  for (btCylinderShape* c : std::vector<btCylinderShape*>{&cy, &cx, &cz}) {
    std::vector<ShapeDesc> out;
    appendShapesFromBullet(*c, id, out);
    REQUIRE(out.size() == 1);
    CHECK(out[0].shape.type == ShapeType::Cylinder);
    CHECK(out[0].shape.dims.x == Approx(0.1));
    CHECK(out[0].shape.dims.y == Approx(0.3));
    for (Vec3 d : {Vec3{1, 0, 0}, Vec3{-1, 0, 0}, Vec3{0, 1, 0}, Vec3{0, -1, 0}, Vec3{0, 0, 1}, Vec3{0, 0, -1}}) {
      const Vec3 ds = rotateInv(out[0].shape.local.q, d);
      const real closed = std::fabs(ds.y) * real(0.3) + real(0.1) * std::sqrt(ds.x * ds.x + ds.z * ds.z);
      CHECK(closed == Approx(bulletSupport(*c, d, true)).margin(1e-5));
      CHECK(supportValue(out[0], d) == Approx(bulletSupport(*c, d, true)).margin(1e-5));
    }
  }
  // Cones (apex direction matters) and capsules, every probe direction.
  btConeShape ky(0.2f, 0.4f);
  btConeShapeX kx(0.2f, 0.4f);
  btConeShapeZ kz(0.2f, 0.4f);
  btCapsuleShape py(0.1f, 0.4f);
  btCapsuleShapeX px(0.1f, 0.4f);
  btCapsuleShapeZ pz(0.1f, 0.4f);
  struct Case {
    btConvexShape* s;
    bool margin;
  };
  for (Case c :
       {Case{&ky, false}, Case{&kx, false}, Case{&kz, false}, Case{&py, true}, Case{&px, true}, Case{&pz, true}}) {
    std::vector<ShapeDesc> out;
    appendShapesFromBullet(*c.s, id, out);
    REQUIRE(out.size() == 1);
    INFO(c.s->getName());
    for (Vec3 d : probeDirections())
      CHECK(supportValue(out[0], d) == Approx(bulletSupport(*c.s, d, c.margin)).margin(1e-5));
  }
  // A convex hull with local scaling: the scaled points as they are, and Bullet's margin (0.04) as the record's
  // sphere-swept radius, so the support is Bullet's with its margin in every direction; without a margin, the points.
  const btScalar pts[] = {0.1f, 0.1f, 0.1f, -0.1f, -0.1f, 0.1f, -0.1f, 0.1f, -0.1f, 0.1f, -0.1f, -0.3f};
  btConvexHullShape hull(pts, 4, 3 * sizeof(btScalar));
  hull.setLocalScaling(btVector3(1, 2, 0.5f));
  std::vector<ShapeDesc> out;
  appendShapesFromBullet(hull, id, out);
  REQUIRE(out.size() == 1);
  CHECK(out[0].shape.type == ShapeType::ConvexHull);
  CHECK(out[0].shape.margin == 0.04f);
  REQUIRE(out[0].hull.size() == 4);  // no points added
  for (int i = 0; i < 4; ++i) {
    CHECK(out[0].hull[size_t(i)].x == Approx(pts[3 * i]));
    CHECK(out[0].hull[size_t(i)].y == Approx(2 * pts[3 * i + 1]));
    CHECK(out[0].hull[size_t(i)].z == Approx(0.5 * pts[3 * i + 2]));
  }
  for (Vec3 d : probeDirections()) CHECK(supportValue(out[0], d) == Approx(bulletSupport(hull, d, true)).margin(1e-5));
  hull.setMargin(0);
  out.clear();
  appendShapesFromBullet(hull, id, out);
  for (Vec3 d : probeDirections()) CHECK(supportValue(out[0], d) == Approx(bulletSupport(hull, d, false)).margin(1e-5));
}

TEST_CASE("Scene format: a convex hull's optional margin reaches the System's hull record", "[cli][hull]") {
  auto scene = [](const std::string& margin) {
    return R"({ "settings": { "steps": 1 }, "bodies": [ { "shape": { "type": "convex_hull", "points": [[0, 0, 0],
      [1, 0, 0], [0, 1, 0], [0, 0, 1]])" +
           margin + R"( }, "mass": 1 } ] })";
  };
  const Scene s = Scene::fromJsonText(scene(R"(, "margin": 0.015625)"), "m.json");
  REQUIRE(s.bodyCount() == 1);
  const BodyDesc d = bodyDescFromBullet(*s.bodies()[0]);
  REQUIRE(d.shapes.size() == 1);
  CHECK(d.shapes[0].shape.type == ShapeType::ConvexHull);
  CHECK(d.shapes[0].shape.margin == 0.015625f);
  CHECK(d.shapes[0].hull.size() == 4);
  // margin 0 is the bare points; without the key, the default (5% of the smallest half extent, 0.5 here)
  CHECK(bodyDescFromBullet(*Scene::fromJsonText(scene(R"(, "margin": 0)"), "z.json").bodies()[0])
            .shapes[0]
            .shape.margin == 0);
  CHECK(bodyDescFromBullet(*Scene::fromJsonText(scene(""), "d.json").bodies()[0]).shapes[0].shape.margin ==
        Approx(0.025));
  for (const char* bad : {R"(, "margin": -0.01)", R"(, "margin": "nan")", R"(, "margin": [1])"}) {
    INFO(bad);
    try {
      Scene::fromJsonText(scene(bad), "bad.json");
      FAIL("accepted");
    } catch (const InputError& e) {
      CHECK(std::string(e.what()).find("margin") != std::string::npos);
    } catch (const std::exception& e) { FAIL("not an InputError: " << e.what()); }
  }
}

TEST_CASE("Bullet import: compounds, multi-spheres and planes", "[cli][bullet]") {
  btCompoundShape comp;
  btSphereShape s(0.1f);
  btCylinderShapeX cx(btVector3(0.3f, 0.1f, 0.1f));
  comp.addChildShape(btTransform(btQuaternion::getIdentity(), btVector3(1, 0, 0)), &s);
  comp.addChildShape(btTransform(btQuaternion(btVector3(0, 0, 1), btScalar(M_PI / 2)), btVector3(0, 1, 0)), &cx);
  std::vector<ShapeDesc> out;
  const Pose body{{0, 0, 0}, quatFromAxisAngle(Vec3{0, 1, 0}, real(M_PI / 2))};
  appendShapesFromBullet(comp, body, out);
  REQUIRE(out.size() == 2);
  CHECK(out[0].shape.type == ShapeType::Sphere);
  // Child at +x, turned 90 degrees about y by the outer pose: at -z.
  CHECK(out[0].shape.local.p.x == Approx(0).margin(1e-6));
  CHECK(out[0].shape.local.p.z == Approx(-1).margin(1e-6));
  // The X cylinder turned 90 degrees about z points along y, then the outer turn about y keeps it on y.
  const Vec3 axis = rotate(out[1].shape.local.q, Vec3{0, 1, 0});
  CHECK(std::fabs(axis.y) == Approx(1).margin(1e-6));

  const btVector3 pos[] = {btVector3(-0.1f, 0, 0), btVector3(0.1f, 0, 0)};
  const btScalar rad[] = {0.1f, 0.15f};
  btMultiSphereShape ms(pos, rad, 2);
  out.clear();
  appendShapesFromBullet(ms, Pose{{0, 0, 0}, {1, 0, 0, 0}}, out);
  REQUIRE(out.size() == 2);
  CHECK(out[1].shape.type == ShapeType::Sphere);
  CHECK(out[1].shape.dims.x == Approx(0.15));
  CHECK(out[1].shape.local.p.x == Approx(0.1));

  const btVector3 c0(0, 0, 0);
  const btScalar one = 1;
  btMultiSphereShape ell(&c0, &one, 1);
  ell.setLocalScaling(btVector3(0.3f, 0.2f, 0.1f));
  out.clear();
  appendShapesFromBullet(ell, Pose{{0, 0, 0}, {1, 0, 0, 0}}, out);
  REQUIRE(out.size() == 1);
  CHECK(out[0].shape.type == ShapeType::Ellipsoid);
  CHECK(out[0].shape.dims.x == Approx(0.3));
  CHECK(out[0].shape.dims.y == Approx(0.2));
  CHECK(out[0].shape.dims.z == Approx(0.1));

  btStaticPlaneShape plane(btVector3(0, 2, 0), 0.5f);
  out.clear();
  appendShapesFromBullet(plane, Pose{{0, 1, 0}, {1, 0, 0, 0}}, out);
  REQUIRE(out.size() == 1);
  CHECK(out[0].shape.type == ShapeType::Plane);
  CHECK(out[0].shape.dims.y == Approx(1));
  CHECK(out[0].shape.plane_d == Approx(1.5));  // y <= 0.5 in the shape frame, shifted up by 1
}

TEST_CASE("Bullet files: every supported shape survives Bullet's serializer and our importer", "[cli][bullet]") {
  const fs::path d = tempDir("bullet");
  BulletWorldFixture w;
  w.save(d / "all_shapes.bullet");

  Scene scene = Scene::load((d / "all_shapes.bullet").string());
  REQUIRE(scene.bodyCount() == w.ptrs.size());
  CHECK(scene.settings.system.step.gravity.y == Approx(-9.81));
  for (size_t i = 0; i < w.ptrs.size(); ++i) {
    INFO("body " << i << " " << w.ptrs[i]->getCollisionShape()->getName());
    const BodyDesc a = bodyDescFromBullet(*w.ptrs[i]);
    const BodyDesc b = bodyDescFromBullet(*scene.bodies()[i]);
    CHECK(a.flags == b.flags);
    CHECK(a.mass == Approx(b.mass));
    CHECK(a.friction == Approx(b.friction));
    CHECK(length(a.pos - b.pos) < 1e-6);
    CHECK(length(a.vel - b.vel) < 1e-6);
    CHECK(length(a.omega - b.omega) < 1e-6);
    CHECK(std::fabs(a.rot.w * b.rot.w + a.rot.x * b.rot.x + a.rot.y * b.rot.y + a.rot.z * b.rot.z) ==
          Approx(1).margin(1e-6));
    REQUIRE(a.shapes.size() == b.shapes.size());
    for (size_t k = 0; k < a.shapes.size(); ++k) {
      const Shape& sa = a.shapes[k].shape;
      const Shape& sb = b.shapes[k].shape;
      CHECK(sa.type == sb.type);
      CHECK(length(sa.dims - sb.dims) < 1e-6);
      CHECK(sa.plane_d == Approx(sb.plane_d).margin(1e-6));
      CHECK(length(sa.local.p - sb.local.p) < 1e-6);
      CHECK(sa.size == Approx(sb.size));
      CHECK(a.shapes[k].hull.size() == b.shapes[k].hull.size());
    }
  }
  // The expected records, against the shapes as built (independent of the file).
  auto shapesOf = [&](size_t i) { return bodyDescFromBullet(*scene.bodies()[i]).shapes; };
  CHECK(shapesOf(0)[0].shape.type == ShapeType::Plane);
  CHECK(shapesOf(1)[0].shape.type == ShapeType::Sphere);
  CHECK(shapesOf(2)[0].shape.dims.z == Approx(0.3));
  CHECK(shapesOf(4)[0].shape.type == ShapeType::Cylinder);
  CHECK(shapesOf(8)[0].shape.type == ShapeType::Capsule);
  CHECK(shapesOf(10)[0].shape.type == ShapeType::Cone);
  CHECK(shapesOf(12)[0].shape.type == ShapeType::ConvexHull);
  CHECK(shapesOf(13).size() == 2);
  CHECK(shapesOf(14)[0].shape.type == ShapeType::Ellipsoid);
  CHECK(shapesOf(15).size() == 3);
  CHECK(bodyDescFromBullet(*scene.bodies()[0]).flags == kBodyFixed);
  CHECK(bodyDescFromBullet(*scene.bodies()[16]).flags == kBodyKinematic);
  CHECK(bodyDescFromBullet(*scene.bodies()[16]).vel.x == Approx(0.3));
  // Per-body gravity survives the file, and the system gets it from the original bodies too.
  {
    System from_file, from_world;
    importBullet(from_file, scene.bodies());
    importBullet(from_world, w.ptrs);
    CHECK(from_file.bodies().gravity[17].y == Approx(-1));
    CHECK(from_world.bodies().gravity[17].y == Approx(-1));
    CHECK(from_file.bodies().gravity[1].y == Approx(-9.81));
    CHECK(from_world.bodies().gravity[1].y == Approx(-9.81));
    CHECK(from_file.bodies().flags[16] == kBodyKinematic);
    for (System* sys : {&from_file, &from_world}) {
      CHECK(sys->bodies().gravity[18].y == Approx(-9.81));  // 7.5 kg: the acceleration, not the force -73.6 N
      CHECK(sys->bodies().gravity[19].y == Approx(-2));     // 1000 kg with its own gravity, not -2000
    }
  }

  for (const char* backend : {"cpu", "bullet"}) {
    INFO(backend);
    const fs::path out = d / backend;
    const CliResult r = runCli("run " + quote((d / "all_shapes.bullet").string()) + " --backend " + backend +
                               " --steps 3 --frames 1 --out " + quote(out.string()));
    INFO(r.out << r.err);
    REQUIRE(r.code == 0);
    std::istringstream csv(slurp(out / "bodies.csv"));
    std::string line;
    int rows = -1;
    while (std::getline(csv, line)) ++rows;
    CHECK(rows == int(w.ptrs.size()));
    const auto j = nlohmann::json::parse(slurp(out / "summary.json"));
    CHECK(j["backend"] == backend);
    CHECK(j["bodies"] == w.ptrs.size());
    if (std::string(backend) == "bullet") CHECK(j["stages"] == nlohmann::json::array({"bullet"}));
  }
  fs::remove_all(d);
}
