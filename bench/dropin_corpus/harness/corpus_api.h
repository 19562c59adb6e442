// The interface between the corpus driver (corpus_main.cpp) and the two example modules it loads: the same
// example sources and harness built once on stock Bullet (`dropin_corpus_stock.so`) and once with the world line
// swapped to dvi::DviDynamicsWorld (`dropin_corpus_dvi.so`). Each module exports one C function,
// `dvisim_corpus_run`; everything else in it is hidden, so the two builds of an example never meet.
#pragma once

#include <string>
#include <vector>

namespace corpus {

// The final state of one rigid body of the world (collision-object order, the order the example created them).
struct BodyState {
  double pos[3] = {0, 0, 0};
  double rot[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};  // row-major rotation matrix
  double mass = 0;                              // 0: static or kinematic
  bool sleeping = false;
};

// One constraint's largest errors of its locked axes over the frames, and over the frames after the first
// second (the examples start some joints apart; both worlds close that first).
struct JointStats {
  std::string type;  // Bullet's class
  int frames = 0;    // frames it was in the world and enabled
  double lin = 0, ang = 0, lin_settled = 0, ang_settled = 0, hinge_lock = -1;
};

struct RunRequest {
  std::string example;  // a name of exampleNames()
  int frames = 300;     // calls of the example's own stepSimulation(1/60)
};

struct RunResult {
  bool ran = false;   // initPhysics and every frame completed
  std::string error;  // the exception's message when not (a refusal of the drop-in world)
  std::string stage;  // where it stopped: "initPhysics" or "frame N"
  int up_axis = 1;    // from the example's setUpAxis
  int frames_done = 0;
  double ms_per_frame = 0;  // mean wall time of the example's stepSimulation over the frames
  double ms_median = 0;     // median frame
  int joints = 0;           // constraints in the world after initPhysics
  double joint_lin = 0;     // largest violation of a locked linear axis over all frames (m)
  double joint_ang = 0;     // largest violation of a locked angular axis over all frames (rad)
  double joint_lin_settled = 0, joint_ang_settled = 0;  // the same over the frames after the first second
  int locked_hinges = 0;                                // hinges with setLimit(lo, lo)
  double locked_hinge = 0;                              // largest |hinge angle - lo| of those over all frames (rad)
  double deepest = 0;  // deepest contact point of the world's manifolds over the last 60 frames (m)
  // The drop-in's solver (ours only; -1 on stock Bullet): iterations of the last sub-step of each frame, mean and
  // largest, and the sub-steps that ended above the tolerance, of all sub-steps.
  double iterations_mean = -1;
  int iterations_max = -1;
  long long substeps = 0, substeps_not_converged = 0;
  std::vector<JointStats> joint_stats;  // per constraint, in the order the example created them
  std::vector<BodyState> bodies;
};

using RunFn = void (*)(const RunRequest*, RunResult*);

}  // namespace corpus

extern "C" {
// Runs one example; never throws (a failure is reported in the result).
void dvisim_corpus_run(const corpus::RunRequest* request, corpus::RunResult* result);
// The examples the module holds, separated by commas.
const char* dvisim_corpus_examples();
}
