// Writes the binary seeds of the fuzz corpus (tests/fuzz/corpus/): .bullet files written by Bullet's own
// serializer and a CES checkpoint written by a short run of the fuzz machine (fuzz_ces_setup.h). Not part of the
// build's default target: `cmake --build build --target fuzz_make_seeds && build/tests/fuzz/fuzz_make_seeds
// tests/fuzz/corpus` regenerates them (docs/HARDENING.md).
#include <btBulletDynamicsCommon.h>
#include <BulletCollision/CollisionShapes/btMultiSphereShape.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "../stock_bullet_world.h"
#include "fuzz_ces_setup.h"

namespace {

// The seed scenes: bodies turned 0.3 rad about y, some of them named in the file.
struct World : dvi::StockBulletWorld {
  std::vector<std::string> names;

  btRigidBody* add(btCollisionShape* s, btScalar mass, const btVector3& pos, const char* name = nullptr) {
    names.push_back(name ? name : "");
    return addBody(s, mass, pos, btQuaternion(btVector3(0, 1, 0), 0.3f));
  }
  void save(const std::filesystem::path& p) {
    btDefaultSerializer ser;
    for (size_t i = 0; i < bodies.size(); ++i)
      if (!names[i].empty()) ser.registerNameForPointer(bodies[i].get(), names[i].c_str());
    world.serialize(&ser);
    std::ofstream f(p, std::ios::binary);
    f.write(reinterpret_cast<const char*>(ser.getBufferPointer()), ser.getCurrentBufferSize());
    std::printf("%s: %d bytes\n", p.string().c_str(), ser.getCurrentBufferSize());
  }
};

}  // namespace

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  if (argc != 2) {
    std::fprintf(stderr, "usage: fuzz_make_seeds CORPUS_DIR\n");
    return 2;
  }
  const fs::path dir = argv[1];
  fs::create_directories(dir / "bullet_file");
  fs::create_directories(dir / "ces_checkpoint");
  {  // the smallest useful scene: ground, sphere, box
    World w;
    w.add(w.keep(new btStaticPlaneShape(btVector3(0, 1, 0), 0)), 0, btVector3(0, 0, 0));
    w.add(w.keep(new btSphereShape(0.1f)), 1, btVector3(0, 1, 0));
    w.add(w.keep(new btBoxShape(btVector3(0.1f, 0.2f, 0.3f))), 2, btVector3(1, 1, 0));
    w.save(dir / "bullet_file" / "plane_sphere_box.bullet");
  }
  {  // every shape the scene loader imports, names, a kinematic body, a body with its own gravity
    World w;
    w.add(w.keep(new btStaticPlaneShape(btVector3(0, 1, 0), 0)), 0, btVector3(0, 0, 0), "ground");
    w.add(w.keep(new btCylinderShapeX(btVector3(0.3f, 0.1f, 0.1f))), 1, btVector3(1, 1, 0), "cylinder");
    w.add(w.keep(new btCapsuleShapeZ(0.1f, 0.4f)), 1, btVector3(2, 1, 0));
    w.add(w.keep(new btConeShape(0.2f, 0.4f)), 1, btVector3(3, 1, 0));
    const btScalar pts[] = {0.1f, 0.1f, 0.1f, -0.1f, -0.1f, 0.1f, -0.1f, 0.1f, -0.1f, 0.1f, -0.1f, -0.1f};
    w.add(w.keep(new btConvexHullShape(pts, 4, 3 * sizeof(btScalar))), 1, btVector3(4, 1, 0), "hull");
    const btVector3 pos[] = {btVector3(-0.1f, 0, 0), btVector3(0.1f, 0, 0)};
    const btScalar rad[] = {0.1f, 0.15f};
    w.add(w.keep(new btMultiSphereShape(pos, rad, 2)), 1, btVector3(5, 1, 0));
    auto* inner = new btCompoundShape();
    inner->addChildShape(btTransform(btQuaternion::getIdentity(), btVector3(0, 0.2f, 0)),
                         w.keep(new btSphereShape(0.05f)));
    auto* comp = new btCompoundShape();
    comp->addChildShape(btTransform(btQuaternion::getIdentity(), btVector3(0.2f, 0, 0)),
                        w.keep(new btSphereShape(0.1f)));
    comp->addChildShape(btTransform(btQuaternion(btVector3(0, 1, 0), 0.5f), btVector3(-0.2f, 0, 0)),
                        w.keep(new btBoxShape(btVector3(0.1f, 0.05f, 0.1f))));
    comp->addChildShape(btTransform::getIdentity(), w.keep(inner));
    w.add(w.keep(comp), 1, btVector3(6, 1, 0), "compound");
    btRigidBody* k = w.add(w.keep(new btBoxShape(btVector3(0.05f, 0.2f, 0.5f))), 0, btVector3(-2, 0.2f, 0), "paddle");
    k->setCollisionFlags(k->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
    k->setActivationState(DISABLE_DEACTIVATION);
    k->setLinearVelocity(btVector3(0.3f, 0, 0));
    w.add(w.keep(new btSphereShape(0.1f)), 5, btVector3(-3, 1, 0))->setGravity(btVector3(0, -2, 0));
    w.save(dir / "bullet_file" / "all_shapes.bullet");
  }
  {  // a checkpoint of the fuzz machine with particles of every shape in flight
    fuzz::CesRig rig;
    for (int i = 0; i < 6; ++i) rig.machine.step();  // ~50 particles: a small seed
    std::ostringstream out(std::ios::binary);
    rig.machine.save(out);
    const fs::path p = dir / "ces_checkpoint" / "state.bin";
    std::ofstream(p, std::ios::binary) << out.str();
    std::printf("%s: %zu bytes, %zu particles\n", p.string().c_str(), out.str().size(), rig.machine.specs().size());
  }
  return 0;
}
