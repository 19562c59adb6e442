// The headless host of Bullet's example programs (our code; the examples themselves are Bullet's files,
// bench/dropin_corpus/third_party/bullet3_examples/, unmodified): what Bullet's example browser gives an example (a GUI
// helper, CommonExampleOptions, the frame loop), without a window. Built twice, into the stock and the drop-in module
// (bench/dropin_corpus/CMakeLists.txt); the drop-in build compiles copies of the examples whose world line alone was
// changed. Each run: the example's CreateFunc, initPhysics, `frames` calls of its own stepSimulation(1/60) (timed one
// by one), the joint errors of every constraint in the world after each frame (outside the timing), and the bodies'
// final state.
#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <stdexcept>
#include <string>
#include <vector>

#include "corpus_api.h"
#ifdef DVISIM_CORPUS_DVI
#include <dvisim/bullet_world.h>
#endif
#include "CommonInterfaces/CommonExampleInterface.h"
#include "CommonInterfaces/CommonGUIHelperInterface.h"
#include "CommonInterfaces/CommonRenderInterface.h"
#include "BasicDemo/BasicExample.h"
#include "Constraints/ConstraintDemo.h"
#include "Constraints/Dof6Spring2Setup.h"
#include "Constraints/TestHingeTorque.h"
#include "ForkLift/ForkLiftDemo.h"
#include "Planar2D/Planar2D.h"
#include "RigidBody/KinematicRigidBodyExample.h"
#include "RollingFrictionDemo/RollingFrictionDemo.h"
#include "Vehicles/Hinge2Vehicle.h"

namespace corpus {
void silencePrintf();  // corpus_stubs.cpp
}

namespace {

// A renderer that draws nothing: KinematicRigidBodyExample registers a texture, a shape and an instance for its
// ground through it.
struct NullRenderer : CommonRenderInterface {
  void init() override {}
  void updateCamera(int) override {}
  void removeAllInstances() override {}
  void removeGraphicsInstance(int) override {}
  const CommonCameraInterface* getActiveCamera() const override { return nullptr; }
  CommonCameraInterface* getActiveCamera() override { return nullptr; }
  void setActiveCamera(CommonCameraInterface*) override {}
  void setLightPosition(const float[3]) override {}
  void setLightPosition(const double[3]) override {}
  void setBackgroundColor(const double[3]) override {}
  void setShadowMapResolution(int) override {}
  void setShadowMapIntensity(double) override {}
  void setShadowMapWorldSize(float) override {}
  void renderScene() override {}
  int getScreenWidth() override { return 0; }
  int getScreenHeight() override { return 0; }
  void resize(int, int) override {}
  int registerGraphicsInstance(int, const float*, const float*, const float*, const float*) override { return -1; }
  int registerGraphicsInstance(int, const double*, const double*, const double*, const double*) override { return -1; }
  void drawLines(const float*, const float[4], int, int, const unsigned int*, int, float) override {}
  void drawLine(const float[4], const float[4], const float[4], float) override {}
  void drawLine(const double[4], const double[4], const double[4], double) override {}
  void drawPoint(const float*, const float[4], float) override {}
  void drawPoint(const double*, const double[4], double) override {}
  void drawPoints(const float*, const float*, int, int, float) override {}
  void drawTexturedTriangleMesh(float[3], float[4], const float*, int, const unsigned int*, int, float[4], int,
                                int) override {}
  int registerShape(const float*, int, const int*, int, int, int) override { return -1; }
  void updateShape(int, const float*, int) override {}
  int registerTexture(const unsigned char*, int, int, bool) override { return -1; }
  void updateTexture(int, const unsigned char*, bool) override {}
  void activateTexture(int) override {}
  void removeTexture(int) override {}
  bool readSingleInstanceTransformToCPU(float*, float*, int) override { return false; }
  void writeSingleInstanceTransformToCPU(const float*, const float*, int) override {}
  void writeSingleInstanceTransformToCPU(const double*, const double*, int) override {}
  void writeSingleInstanceColorToCPU(const float*, int) override {}
  void writeSingleInstanceColorToCPU(const double*, int) override {}
  void writeSingleInstanceScaleToCPU(const float*, int) override {}
  void writeSingleInstanceScaleToCPU(const double*, int) override {}
  void writeSingleInstanceSpecularColorToCPU(const double*, int) override {}
  void writeSingleInstanceSpecularColorToCPU(const float*, int) override {}
  void writeSingleInstanceFlagsToCPU(int, int) override {}
  int getTotalNumInstances() const override { return 0; }
  void writeTransforms() override {}
  void clearZBuffer() override {}
  struct GLInstanceRendererInternalData* getInternalData() override {
    return nullptr;
  }
};

// The browser gives each world a debug drawer (TestHingeTorque sets its mode); this one draws nothing.
struct NullDebugDraw : btIDebugDraw {
  int mode = 0;
  void drawLine(const btVector3&, const btVector3&, const btVector3&) override {}
  void drawContactPoint(const btVector3&, const btVector3&, btScalar, int, const btVector3&) override {}
  void reportErrorWarning(const char*) override {}
  void draw3dText(const btVector3&, const char*) override {}
  void setDebugMode(int m) override { mode = m; }
  int getDebugMode() const override { return mode; }
};

// Bullet's DummyGUIHelper, remembering what the harness needs: the example's world (every example hands it to
// createPhysicsDebugDrawer and autogenerateGraphicsObjects) and its up axis.
struct HeadlessGui : DummyGUIHelper {
  NullRenderer renderer;
  NullDebugDraw drawer;
  btDiscreteDynamicsWorld* world = nullptr;
  int up_axis = 1;
  CommonRenderInterface* getRenderInterface() override { return &renderer; }
  void setUpAxis(int axis) override { up_axis = axis; }
  void createPhysicsDebugDrawer(btDiscreteDynamicsWorld* w) override {
    world = w;
    w->setDebugDrawer(&drawer);
  }
  void autogenerateGraphicsObjects(btDiscreteDynamicsWorld* w) override { world = w; }
};

struct Entry {
  const char* name;
  CommonExampleInterface::CreateFunc* create;
};

const Entry kExamples[] = {
    {"BasicDemo", BasicExampleCreateFunc},
    {"ForkLiftDemo", ForkLiftCreateFunc},
    {"Hinge2Vehicle", Hinge2VehicleCreateFunc},
    {"ConstraintDemo", AllConstraintCreateFunc},
    {"Dof6Spring2Setup", Dof6Spring2CreateFunc},
    {"TestHingeTorque", TestHingeTorqueCreateFunc},
    {"RollingFrictionDemo", RollingFrictionCreateFunc},
    {"Planar2D", Planar2DCreateFunc},
    {"KinematicRigidBodyExample", KinematicRigidBodyExampleCreateFunc},
};

double angleBetween(const btVector3& a, const btVector3& b) {
  return std::atan2(double(a.cross(b).length()), double(a.dot(b)));
}

double wrapAngle(double a) { return std::fabs(double(btNormalizeAngle(btScalar(a)))); }

// The largest violation of a constraint's locked linear (lin, m) and angular (ang, rad) axes now, and for a
// hinge locked by setLimit(lo, lo) its |angle - lo| (hinge_lock, -1 otherwise). Limits with a range and motors
// are not errors; a gear has no position error.
struct JointError {
  double lin = 0, ang = 0, hinge_lock = -1;
};

template <class Dof6>
void dof6Error(Dof6* c, JointError& e) {
  c->calculateTransforms();
  btVector3 llo, lhi, alo, ahi;
  c->getLinearLowerLimit(llo);
  c->getLinearUpperLimit(lhi);
  c->getAngularLowerLimit(alo);
  c->getAngularUpperLimit(ahi);
  for (int i = 0; i < 3; ++i) {
    if (llo[i] == lhi[i]) e.lin = std::max(e.lin, std::fabs(double(c->getRelativePivotPosition(i) - llo[i])));
    if (alo[i] == ahi[i]) e.ang = std::max(e.ang, wrapAngle(c->getAngle(i) - alo[i]));
  }
}

JointError jointError(btTypedConstraint* tc) {
  JointError e;
  const btTransform& ta = tc->getRigidBodyA().getCenterOfMassTransform();
  const btTransform& tb = tc->getRigidBodyB().getCenterOfMassTransform();
  switch (tc->getConstraintType()) {
    case POINT2POINT_CONSTRAINT_TYPE: {
      auto* c = static_cast<btPoint2PointConstraint*>(tc);
      e.lin = (ta * c->getPivotInA() - tb * c->getPivotInB()).length();
      break;
    }
    case HINGE_CONSTRAINT_TYPE: {
      auto* c = static_cast<btHingeConstraint*>(tc);
      const btTransform fa = ta * c->getAFrame(), fb = tb * c->getBFrame();
      e.lin = (fa.getOrigin() - fb.getOrigin()).length();
      e.ang = angleBetween(fa.getBasis().getColumn(2), fb.getBasis().getColumn(2));
      if (c->getLowerLimit() == c->getUpperLimit()) {  // setLimit(lo, lo): Bullet's hasLimit() is false there
        e.hinge_lock = wrapAngle(c->getHingeAngle() - c->getLowerLimit());
        e.ang = std::max(e.ang, e.hinge_lock);
      }
      break;
    }
    case SLIDER_CONSTRAINT_TYPE: {
      auto* c = static_cast<btSliderConstraint*>(tc);
      const btTransform fa = ta * c->getFrameOffsetA(), fb = tb * c->getFrameOffsetB();
      const btTransform rel = fa.inverse() * fb;  // the slide along x of frame A, the rotation about it
      const btVector3 d = rel.getOrigin();
      e.lin = std::sqrt(double(d.y() * d.y() + d.z() * d.z()));
      if (c->getLowerLinLimit() == c->getUpperLinLimit())
        e.lin = std::max(e.lin, std::fabs(double(d.x() - c->getLowerLinLimit())));
      e.ang = angleBetween(fa.getBasis().getColumn(0), fb.getBasis().getColumn(0));
      if (c->getLowerAngLimit() == c->getUpperAngLimit()) {
        const btMatrix3x3& r = rel.getBasis();
        e.ang = std::max(e.ang, wrapAngle(std::atan2(double(r[2][1]), double(r[1][1])) - c->getLowerAngLimit()));
      }
      break;
    }
    case CONETWIST_CONSTRAINT_TYPE: {
      auto* c = static_cast<btConeTwistConstraint*>(tc);
      e.lin = ((ta * c->getAFrame()).getOrigin() - (tb * c->getBFrame()).getOrigin()).length();
      break;
    }
    case D6_CONSTRAINT_TYPE:
    case D6_SPRING_CONSTRAINT_TYPE: dof6Error(static_cast<btGeneric6DofConstraint*>(tc), e); break;
    case D6_SPRING_2_CONSTRAINT_TYPE:
    case FIXED_CONSTRAINT_TYPE: dof6Error(static_cast<btGeneric6DofSpring2Constraint*>(tc), e); break;
    default: break;
  }
  return e;
}

const char* typeName(btTypedConstraint* c) {
  switch (c->getConstraintType()) {
    case POINT2POINT_CONSTRAINT_TYPE: return "point-to-point";
    case HINGE_CONSTRAINT_TYPE: return "hinge";
    case SLIDER_CONSTRAINT_TYPE: return "slider";
    case CONETWIST_CONSTRAINT_TYPE: return "cone-twist";
    case D6_CONSTRAINT_TYPE: return "6-DoF";
    case D6_SPRING_CONSTRAINT_TYPE: return "6-DoF spring";
    case D6_SPRING_2_CONSTRAINT_TYPE: return "6-DoF spring 2";
    case GEAR_CONSTRAINT_TYPE: return "gear";
    case FIXED_CONSTRAINT_TYPE: return "fixed";
    default: return "other";
  }
}

// Joint statistics keyed by the constraint's address in creation order (an example may remove and re-add one).
struct JointTracker {
  std::vector<btTypedConstraint*> seen;
  void measure(btDiscreteDynamicsWorld* w, bool settled, corpus::RunResult& r) {
    for (int i = 0; i < w->getNumConstraints(); ++i) {
      btTypedConstraint* c = w->getConstraint(i);
      if (!c->isEnabled()) continue;
      size_t k = size_t(std::find(seen.begin(), seen.end(), c) - seen.begin());
      if (k == seen.size()) {
        seen.push_back(c);
        r.joint_stats.push_back(corpus::JointStats{});
        r.joint_stats.back().type = typeName(c);
      }
      corpus::JointStats& s = r.joint_stats[k];
      const JointError e = jointError(c);
      ++s.frames;
      s.lin = std::max(s.lin, e.lin), s.ang = std::max(s.ang, e.ang);
      if (settled) s.lin_settled = std::max(s.lin_settled, e.lin), s.ang_settled = std::max(s.ang_settled, e.ang);
      if (e.hinge_lock >= 0) s.hinge_lock = std::max(s.hinge_lock, e.hinge_lock);
      r.joint_lin = std::max(r.joint_lin, e.lin), r.joint_ang = std::max(r.joint_ang, e.ang);
      if (settled)
        r.joint_lin_settled = std::max(r.joint_lin_settled, e.lin),
        r.joint_ang_settled = std::max(r.joint_ang_settled, e.ang);
      if (e.hinge_lock >= 0) r.locked_hinge = std::max(r.locked_hinge, e.hinge_lock);
    }
  }
};

void countLockedHinges(btDiscreteDynamicsWorld* w, corpus::RunResult& r) {
  r.joints = w->getNumConstraints();
  for (int i = 0; i < w->getNumConstraints(); ++i)
    if (jointError(w->getConstraint(i)).hinge_lock >= 0) ++r.locked_hinges;
}

// The deepest penetration among the contact points of the world's persistent manifolds (the drop-in world fills
// Bullet's manifolds from its own contacts).
double deepestContact(btDiscreteDynamicsWorld* w) {
  btDispatcher* d = w->getDispatcher();
  double deepest = 0;
  for (int i = 0; i < d->getNumManifolds(); ++i) {
    const btPersistentManifold* m = d->getManifoldByIndexInternal(i);
    for (int k = 0; k < m->getNumContacts(); ++k)
      deepest = std::max(deepest, -double(m->getContactPoint(k).getDistance()));
  }
  return deepest;
}

void readBodies(btDiscreteDynamicsWorld* w, corpus::RunResult& r) {
  const btCollisionObjectArray& objs = w->getCollisionObjectArray();
  for (int i = 0; i < objs.size(); ++i) {
    const btRigidBody* b = btRigidBody::upcast(objs[i]);
    if (!b) continue;
    corpus::BodyState s;
    const btTransform& t = b->getCenterOfMassTransform();
    for (int k = 0; k < 3; ++k) {
      s.pos[k] = t.getOrigin()[k];
      for (int j = 0; j < 3; ++j) s.rot[3 * k + j] = t.getBasis()[k][j];
    }
    s.mass = (b->isStaticOrKinematicObject() || b->getInvMass() == 0) ? 0 : 1 / double(b->getInvMass());
    s.sleeping = s.mass > 0 && b->getActivationState() == ISLAND_SLEEPING;
    r.bodies.push_back(s);
  }
}

// The drop-in's solver statistics after a frame (the drop-in module only).
struct SolverTally {
  double sum = 0;
  int frames = 0;
  void add(btDiscreteDynamicsWorld* w, corpus::RunResult& r) {
#ifdef DVISIM_CORPUS_DVI
    const auto* ours = dynamic_cast<dvi::DviDynamicsWorld*>(w);
    if (!ours) return;
    const int it = ours->system().lastStats().iterations;
    sum += it, ++frames;
    r.iterations_mean = sum / frames;
    r.iterations_max = std::max(r.iterations_max, it);
    r.substeps = ours->convergence().steps;
    r.substeps_not_converged = ours->convergence().steps_not_converged;
#else
    (void)w, (void)r;
#endif
  }
};

void runExample(const Entry& ex, const corpus::RunRequest& q, corpus::RunResult& r) {
  using Clock = std::chrono::steady_clock;
  corpus::silencePrintf();
  HeadlessGui gui;
  CommonExampleOptions options(&gui);
  CommonExampleInterface* example = ex.create(options);  // leaked when a step throws: its state is unknown
  r.stage = "initPhysics";
  example->initPhysics();
  r.up_axis = gui.up_axis;
  if (!gui.world) throw std::runtime_error("the example never handed its world to the GUI helper");
  countLockedHinges(gui.world, r);
  std::vector<double> ms;
  JointTracker joints;
  SolverTally solver;
  for (int f = 0; f < q.frames; ++f) {
    r.stage = "frame " + std::to_string(f + 1);
    const auto t0 = Clock::now();
    example->stepSimulation(1.f / 60.f);
    ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    joints.measure(gui.world, f >= 60, r);  // settled: after the first 60 frames
    solver.add(gui.world, r);
    if (f >= q.frames - 60) r.deepest = std::max(r.deepest, deepestContact(gui.world));
    r.frames_done = f + 1;
  }
  readBodies(gui.world, r);
  double sum = 0;
  for (double m : ms) sum += m;
  r.ms_per_frame = ms.empty() ? 0 : sum / double(ms.size());
  std::sort(ms.begin(), ms.end());
  r.ms_median = ms.empty() ? 0 : ms[ms.size() / 2];
  r.stage.clear();
  r.ran = true;
  example->exitPhysics();
  delete example;
}

}  // namespace

extern "C" __attribute__((visibility("default"))) void dvisim_corpus_run(const corpus::RunRequest* q,
                                                                         corpus::RunResult* r) {
  *r = corpus::RunResult{};
  for (const Entry& ex : kExamples) {
    if (q->example != ex.name) continue;
    try {
      runExample(ex, *q, *r);
    } catch (const std::exception& e) { r->error = e.what(); } catch (...) {
      r->error = "unknown exception";
    }
    return;
  }
  r->error = "no example named " + q->example;
}

extern "C" __attribute__((visibility("default"))) const char* dvisim_corpus_examples() {
  static const std::string names = [] {
    std::string s;
    for (const Entry& ex : kExamples) s += (s.empty() ? "" : ",") + std::string(ex.name);
    return s;
  }();
  return names.c_str();
}
