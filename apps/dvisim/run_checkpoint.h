// Checkpoints of scene runs (`dvisim run SCENE`, on one process or under mpirun): one format for both. A checkpoint is
// a folder of pieces (chrono_like/checkpoint_piece.h, format DVIMPI02: bodies' states and the last step's contact
// impulses and normals under scene ids and contact keys, checksummed) and manifest.json naming how many there are, the step, the
// clock, dt, the body count and the scene file's checksum. Under mpirun each process writes its piece; a single
// process writes one piece with all its bodies (the case K = 1), so either resumes on any number of processes.
//
// Where they are: a run that ends (done, interrupted by SIGINT/SIGTERM, diverged or failed) leaves OUT/checkpoint/;
// with a period (--checkpoint-every N, settings.checkpoint_every) the run also writes RUN/checkpoints/step_<N>/ while
// it runs, RUN being the temporary results folder beside OUT (.NAME.tmp-PID-K, output.h: ResultDir), each through a
// temporary folder renamed into place once complete, the newest two kept. A run killed outright (SIGKILL, a node or
// out-of-memory failure) leaves that folder behind, and `--resume OUT` finds the newest complete checkpoint there.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "chrono_like/checkpoint_piece.h"

namespace dvi {
class Scene;
class System;
struct SystemConfig;
}  // namespace dvi

namespace runckpt {

class Periodic;

// The scene file's FNV-1a 64 checksum in hex ("none" for an embedded scene): a resume must run the same file.
std::string sceneChecksum(const dvi::Scene& scene);

// manifest.json of a checkpoint of `processes` pieces (piece_p0.bin ... piece_p<K-1>.bin).
std::string manifestText(int processes, int64_t step, double time, double dt, size_t bodies, const dvi::Scene& scene);

// A single process's checkpoint into the folder `cdir` (made; its files written atomically): one piece with every
// moving (dynamic or kinematic) body of `sys` and its last step's contact impulses, then the manifest. `sys` holds
// the scene's bodies in scene order and is synced to the host.
void writeSingle(const dvi::System& sys, const dvi::Scene& scene, const std::string& cdir);

struct Resumed {
  std::vector<dvi::MotionState> states;       // by scene id
  std::vector<uint8_t> present;               // 1 where a piece held the body (every dynamic one; kinematic: optional)
  std::vector<dvi::ContactImpulse> impulses;  // ascending keys, each key once
  double time = 0;
  int64_t step = 0;
};

// The checkpoint in folder `cdir`, checked against the scene (its flags by scene id), the run's dt and itself
// (every piece's checksum, every dynamic body exactly once, nothing but dynamic or kinematic bodies): InputError
// "<what>: <label>...: <problem>" otherwise.
Resumed read(const std::string& cdir, const std::string& what, const std::string& label, const dvi::Scene& scene,
             const std::vector<uint8_t>& flags, double dt);

// The checkpoint `--resume DIR` continues: DIR/checkpoint, or the newest periodic checkpoint of a run killed while it
// wrote DIR (DIR's temporary folders beside it, .NAME.tmp-*/checkpoints/step_*), whichever is at the later step,
// among those of the scene file with this checksum (any, when `checksum` is empty). Its folder, and in `label` its
// name for messages; "" when there is none.
std::string locate(const std::string& dir, const std::string& checksum, std::string* label = nullptr);
// Whether `dir` holds a scene run's checkpoint (locate finds one for some scene), not a CES machine's.
bool isSceneCheckpoint(const std::string& dir);

// A single process's System put in the checkpoint's state: the bodies it holds, the clock, the warm start.
void restore(dvi::System& sys, const Resumed& r);

// `--resume dir` of a single process's run of `scene` to step `steps`: the checkpoint locate() finds, read and
// checked (InputError: none there, another scene file or dt, damaged, or at `steps` already); `folder` its folder.
// `say`: print which one on stdout.
Resumed readResume(const std::string& dir, const dvi::Scene& scene, const dvi::SystemConfig& cfg, int64_t steps,
                   std::string& folder, bool say = true);

// A single process's run ends: its checkpoint into `cdir` from the state of `sys` when the run did not fail (done or
// interrupted, the state finite); after a failure, the newest periodic one, else the one it resumed from
// (`resumed_from`, may be ""). Removes the periodic ones. Whether `cdir` holds a checkpoint.
bool finalCheckpoint(dvi::System& sys, const dvi::Scene& scene, const Periodic& periodic, const std::string& cdir,
                     bool failed, const std::string& resumed_from);

// After a resumed run has put its results in place as `out`: the temporary folder of the killed run it resumed from
// (`resumed_from` inside it), when that run wrote `out` too, is superseded and removed.
void forgetKilledRun(const std::string& resumed_from, const std::string& out);

// The periodic checkpoints of a run into RUN/checkpoints/: step_<N>/ (N zero-padded, so names sort by step), the
// newest two kept.
class Periodic {
 public:
  Periodic(std::string run_dir, int64_t every) : dir_(std::move(run_dir) + "/checkpoints"), every_(every) {}
  bool due(int64_t step) const { return every_ > 0 && step > 0 && step % every_ == 0; }
  // The folder the pieces of step `step` go to (a temporary name; made by the caller that passes make).
  std::string begin(int64_t step, bool make = true) const;
  // Puts begin(step)'s folder in place (one rename: a reader sees it complete or not at all) and removes all but the
  // newest two.
  void commit(int64_t step);
  // The newest complete one, "" when there is none.
  std::string newest() const;
  // Removes checkpoints/ (the run's own checkpoint/ has replaced it).
  void clear() const;

 private:
  std::string name(int64_t step) const;
  std::string dir_;
  int64_t every_;
};

}  // namespace runckpt
