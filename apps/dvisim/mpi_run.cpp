#include "mpi_run.h"

#include <mpi.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "chrono_like/base/errors.h"
#include "chrono_like/bullet/bullet_import.h"
#include "chrono_like/io/output.h"
#include "chrono_like/io/run_control.h"
#include "chrono_like/io/scene.h"
#include "chrono_like/mpi/distributed_system.h"
#include "chrono_like/base/checksum.h"
#include "chrono_like/io/input_limits.h"
#include "chrono_like/checkpoint_piece.h"
#include "chrono_like/mpi/mpi_collectives.h"
#include "gpu/gpu_factory.h"
#include "progress.h"
#include "run_checkpoint.h"

namespace {

bool launchedByMpirun() {
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"})
    if (std::getenv(v)) return true;
  return false;
}

}  // namespace

MpiSession::MpiSession(int* argc, char*** argv) {
  if (launchedByMpirun()) MPI_Init(argc, argv);
}

MpiSession::~MpiSession() {
  int init = 0, done = 0;
  MPI_Initialized(&init);
  MPI_Finalized(&done);
  if (init && !done) MPI_Finalize();
}

void mpiAbort(int code) {
  std::fflush(stdout);
  std::fflush(stderr);
  MPI_Abort(MPI_COMM_WORLD, code);
}

bool mpiInitialized() {
  int init = 0;
  MPI_Initialized(&init);
  return init != 0;
}

int mpiProcesses() {
  int init = 0, n = 1;
  MPI_Initialized(&init);
  if (init) MPI_Comm_size(MPI_COMM_WORLD, &n);
  return n;
}

int mpiRank() {
  int init = 0, r = 0;
  MPI_Initialized(&init);
  if (init) MPI_Comm_rank(MPI_COMM_WORLD, &r);
  return r;
}

namespace {
// The size of, or this process's rank in, the processes sharing its host (MPI-3 shared-memory split); 1 or 0
// without mpirun.
int hostQuery(bool size) {
  int init = 0, v = size ? 1 : 0;
  MPI_Initialized(&init);
  if (!init) return v;
  MPI_Comm host = MPI_COMM_NULL;
  MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, mpiRank(), MPI_INFO_NULL, &host);
  if (size)
    MPI_Comm_size(host, &v);
  else
    MPI_Comm_rank(host, &v);
  MPI_Comm_free(&host);
  return v;
}
}  // namespace

int mpiHostProcesses() { return hostQuery(true); }
int mpiHostRank() { return hostQuery(false); }

void mpiBarrier() {
  int init = 0;
  MPI_Initialized(&init);
  if (init) MPI_Barrier(MPI_COMM_WORLD);
}

int mpiBroadcast(int value) {
  int init = 0;
  MPI_Initialized(&init);
  if (init) MPI_Bcast(&value, 1, MPI_INT, 0, MPI_COMM_WORLD);
  return value;
}

std::vector<long long> mpiGatherToRoot(const std::vector<long long>& mine) {
  int init = 0;
  MPI_Initialized(&init);
  if (!init) return mine;
  const int n = mpiProcesses(), me = mpiRank();
  int count = int(mine.size());
  std::vector<int> counts(size_t(n), 0), displ(size_t(n), 0);
  MPI_Gather(&count, 1, MPI_INT, counts.data(), 1, MPI_INT, 0, MPI_COMM_WORLD);
  int total = 0;
  for (int q = 0; q < n; ++q) displ[size_t(q)] = total, total += counts[size_t(q)];
  std::vector<long long> all(me == 0 ? size_t(total) : size_t(0));
  MPI_Gatherv(mine.data(), count, MPI_LONG_LONG, all.data(), counts.data(), displ.data(), MPI_LONG_LONG, 0,
              MPI_COMM_WORLD);
  return all;
}

namespace {

// Process 0's results directory (ResultDir, made before the run so that the frames go into it), its path on every
// process; an unusable --out stops every process with InputError.
std::string sharedResultDir(std::unique_ptr<dvi::ResultDir>& rd, const std::string& out, bool root) {
  std::string path, why;
  if (root) try {
      rd = std::make_unique<dvi::ResultDir>(out);
      path = rd->path();
    } catch (const std::exception& e) { why = e.what(); }
  const std::string& msg = why.empty() ? path : why;
  int head[2] = {why.empty() ? 0 : 1, int(msg.size())};
  MPI_Bcast(head, 2, MPI_INT, 0, MPI_COMM_WORLD);
  std::string text(size_t(head[1]), '\0');
  if (root) text = msg;
  MPI_Bcast(text.data(), head[1], MPI_CHAR, 0, MPI_COMM_WORLD);
  if (head[0]) throw dvi::InputError(root ? why : "--out: " + text);
  return text;
}

// Frame `index` at `time`: each process writes its piece (process 0: the fixed and kinematic bodies too) as
// frame_<index>_p<rank>.vtp, process 0 the frame_<index>.pvtp that names the pieces and its frames.pvd entry.
void writeFramePieces(const dvi::DistributedSystem& sys, const std::vector<dvi::real>& sizes, const std::string& dir,
                      int index, double time, dvi::PvdSeries* series) {
  std::vector<dvi::BodyState> states;
  std::vector<int64_t> ids;
  const bool root = sys.rank() == 0, before = sys.stepCount() == 0;  // before the first step: process 0 has all
  auto add = [&](int32_t id, const dvi::MotionState& m) {
    states.push_back(dvi::BodyState{m.pos, m.rot, m.vel, m.omega, sizes[size_t(id)]});
    ids.push_back(int64_t(id));
  };
  if (!before) {  // the owned bodies in one copy; process 0 adds the fixed and kinematic ones
    const std::vector<dvi::MotionState> owned = sys.ownedStates();
    for (size_t j = 0; j < owned.size(); ++j) add(sys.ownedIds()[j], owned[j]);
  }
  for (size_t id = 0; id < sys.bodyCount() && root; ++id)
    if (before || sys.replicated(int32_t(id))) add(int32_t(id), sys.stateOf(int32_t(id)));
  if (!before) {  // scene order in the piece
    std::vector<size_t> order(ids.size());
    for (size_t j = 0; j < order.size(); ++j) order[j] = j;
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return ids[a] < ids[b]; });
    std::vector<dvi::BodyState> s2;
    std::vector<int64_t> i2;
    for (size_t j : order) s2.push_back(states[j]), i2.push_back(ids[j]);
    states.swap(s2);
    ids.swap(i2);
  }
  char name[48];
  std::snprintf(name, sizeof name, "frame_%04d_p%d.vtp", index, sys.rank());
  dvi::writeFileAtomic(dir + "/" + name, dvi::vtpFrame(states, &ids));
  if (!series) return;
  std::vector<std::string> pieces;
  for (int q = 0; q < sys.processes(); ++q) {
    std::snprintf(name, sizeof name, "frame_%04d_p%d.vtp", index, q);
    pieces.push_back(name);
  }
  std::snprintf(name, sizeof name, "frame_%04d.pvtp", index);
  series->addFile(time, name, dvi::pvtpFrame(pieces));
}

// A checkpoint of the run into the folder `cdir` (run_checkpoint.h): each process its piece, then process 0 the
// manifest naming them (the step, the clock, dt, the scene and its checksum).
void writeCheckpoint(const dvi::DistributedSystem& sys, const dvi::Scene& scene, double dt, const std::string& cdir) {
  if (sys.rank() == 0) std::filesystem::create_directories(cdir);
  MPI_Barrier(MPI_COMM_WORLD);
  dvi::writeFileAtomic(cdir + "/piece_p" + std::to_string(sys.rank()) + ".bin", dvi::encodePiece(sys.checkpointPiece()),
                       dvi::Durability::Synced);
  MPI_Barrier(MPI_COMM_WORLD);  // every piece in place before the manifest names them
  if (sys.rank() == 0)
    dvi::writeFileAtomic(
        cdir + "/manifest.json",
        runckpt::manifestText(sys.processes(), sys.stepCount(), sys.time(), dt, sys.bodyCount(), scene),
        dvi::Durability::Synced);
}

// A periodic checkpoint (every process calls it at the same step): the pieces and manifest into a temporary folder,
// which process 0 then renames into place (Periodic::commit keeps the newest two).
void writePeriodic(const dvi::DistributedSystem& sys, const dvi::Scene& scene, double dt, runckpt::Periodic& periodic,
                   int64_t step) {
  const std::string tmp = periodic.begin(step, sys.rank() == 0);
  writeCheckpoint(sys, scene, dt, tmp);
  if (sys.rank() == 0) periodic.commit(step);
}

// What a run over processes counted, for its summary.
struct MpiTally {
  int64_t done, first, steps, contacts, iterations, moved;
  double relative, wall;
  int frames;
};

// summary.json of a run over processes (process 0), the keys of one process's run and the decomposition's.
nlohmann::json mpiSummary(const dvi::Scene& scene, const dvi::SystemConfig& cfg, const dvi::DistributedSystem& sys,
                          bool gpu, const MpiTally& t, int code) {
  nlohmann::json summary;
  summary["scene"] = scene.source;
  summary["scene_name"] = scene.name;
  summary["bodies"] = scene.bodies().size();
  summary["dt"] = cfg.step.dt;
  summary["steps"] = t.done;
  summary["steps_planned"] = t.steps;
  summary["sim_time"] = double(t.done) * cfg.step.dt;
  summary["backend"] = gpu ? "gpu" : "cpu";
  summary["processes"] = sys.processes();
  summary["solver"] = dvi::solverName(cfg.solver.type);
  summary["collision"] = "native";
  summary["iterations_mean"] = t.done > 0 ? double(t.iterations) / double(t.done) : 0.0;
  summary["residual_final"] = t.relative;
  summary["contacts_mean"] = t.done > 0 ? double(t.contacts) / double(t.done) : 0.0;
  summary["migrations"] = t.moved;
  if (t.first > 0) summary["resumed_from_step"] = t.first;
  summary["checkpoint"] = "checkpoint/";
  summary["rebalances"] = sys.migrations().rebalances;
  summary["frames"] = t.frames;
  summary["status"] = dvi::runStatusName(code);
  summary["wall_time_s"] = t.wall;
  summary["ms_per_step"] = t.done > t.first ? 1000.0 * t.wall / double(t.done - t.first) : 0.0;
  return summary;
}

}  // namespace

int runSceneMpi(const dvi::Scene& scene, const dvi::SystemConfig& cfg, int64_t steps,
                const std::vector<int64_t>& frame_at, const std::string& out, const std::string& backend,
                const std::string& resume, int64_t checkpoint_every) {
  if (backend != "auto" && backend != "cpu" && backend != "gpu")
    throw dvi::InputError("--backend " + backend + ": not available over several processes (MPI runs cpu or gpu)");
  // gpu: one device a process, host rank i on device i (mod the devices); auto: the CPU.
  const bool gpu = backend == "gpu";
  if (gpu && dvi::selectGpu(mpiHostRank()) < 0)
    throw dvi::InputError("--backend gpu: process " + std::to_string(mpiRank()) + " sees no CUDA device");
  dvi::DistributedSystem sys(
      MPI_COMM_WORLD, cfg, {},
      gpu ? dvi::DistributedSystem::LocalFactory([](const dvi::SystemConfig& c) { return dvi::makeGpuSystem(c); })
          : nullptr);
  const std::vector<btRigidBody*>& bodies = scene.bodies();
  std::vector<dvi::real> sizes;
  std::vector<uint8_t> flags;
  for (size_t i = 0; i < bodies.size(); ++i) {
    const dvi::BodyDesc d = dvi::bodyDescForSystem(bodies[i], i, cfg.step.gravity);
    dvi::real m = dvi::real(1e30);
    for (const auto& sh : d.shapes) m = std::fmin(m, sh.shape.size);
    sizes.push_back(m);
    flags.push_back(d.flags);
    sys.addBody(d);
  }
  int64_t first = 0;  // the step a resumed run starts from
  std::string resumed_from;
  if (!resume.empty()) {
    const runckpt::Resumed r = runckpt::readResume(resume, scene, cfg, steps, resumed_from, mpiRank() == 0);
    sys.restore(r.states, r.impulses, r.time, r.step);
    first = r.step;
  }
  const bool root = sys.rank() == 0;
  std::unique_ptr<dvi::ResultDir> rd;
  const std::string dir = sharedResultDir(rd, out, root);
  std::unique_ptr<dvi::PvdSeries> series = root ? std::make_unique<dvi::PvdSeries>(dir) : nullptr;
  if (root)
    std::printf("scene: %s (%zu bodies), %lld steps of %g s on %d processes (MPI)\n", scene.name.c_str(), bodies.size(),
                (long long)steps, cfg.step.dt, sys.processes());
  Progress progress(steps, root);  // process 0: a bar on a terminal, else a line every 10 %
  int64_t contacts = 0, iterations = 0, done = first;
  runckpt::Periodic periodic(dir, checkpoint_every);  // every process names the same folders (process 0's)
  int frames = 0;
  size_t next_frame = 0;
  double relative = 0;
  // SIGINT or SIGTERM on any process stops every process after the same step (one reduction a step); the results
  // so far are written with status "interrupted", exit code 4, as one process's run does.
  dvi::installStopHandlers();
  bool interrupted = false;
  const auto t0 = std::chrono::steady_clock::now();
  while (next_frame < frame_at.size() && frame_at[next_frame] < first) ++next_frame;
  for (int64_t k = first;; ++k) {
    for (; next_frame < frame_at.size() && frame_at[next_frame] == k; ++next_frame)
      writeFramePieces(sys, sizes, dir, frames++, double(k) * cfg.step.dt, series.get());
    if (k == steps) break;
    int stop = dvi::stopRequested() ? 1 : 0;
    MPI_Allreduce(MPI_IN_PLACE, &stop, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
    if (stop) {
      interrupted = true;
      break;
    }
    sys.step();
    done = k + 1;
    contacts += sys.local()->lastStats().contacts;
    iterations += sys.local()->lastStats().iterations;  // the same on every process (collective solve)
    relative = double(sys.local()->lastStats().relative_residual);
    if (root) progress.update(k + 1);
    if (periodic.due(done)) writePeriodic(sys, scene, double(cfg.step.dt), periodic, done);
  }
  if (root) progress.finish();
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  contacts = dvi::mpiSum(MPI_COMM_WORLD, contacts);
  const std::vector<dvi::MotionState> all = sys.gatherState();
  int64_t moved = 0;
  for (int64_t v : sys.migrations().sent) moved += v;
  moved = dvi::mpiSum(MPI_COMM_WORLD, moved);
  writeCheckpoint(sys, scene, double(cfg.step.dt), dir + "/checkpoint");
  MPI_Barrier(MPI_COMM_WORLD);  // every piece written before process 0 puts the directory in place
  if (root) periodic.clear();
  const int code = interrupted ? int(dvi::kExitInterrupted) : int(dvi::kExitDone);
  if (!root) return code;
  std::vector<dvi::BodyState> state(all.size());
  for (size_t i = 0; i < all.size(); ++i)
    state[i] = dvi::BodyState{all[i].pos, all[i].rot, all[i].vel, all[i].omega, sizes[i]};
  const MpiTally tally{done, first, steps, contacts, iterations, moved, relative, wall, frames};
  const nlohmann::json summary = mpiSummary(scene, cfg, sys, gpu, tally, code);
  dvi::writeBodiesCsv(dir + "/bodies.csv", state);
  dvi::writeSummary(dir + "/summary.json", summary);
  series.reset();  // frames.pvd closed before the directory moves
  rd->commit();
  runckpt::forgetKilledRun(resumed_from, rd->out());
  std::printf("results: %s/ (summary.json, bodies.csv%s), %.3f s wall, %.2f ms/step\n", rd->out().c_str(),
              frames ? (", " + std::to_string(frames) + " frames: frame_NNNN.pvtp + pieces, frames.pvd").c_str() : "",
              wall, done > first ? 1000.0 * wall / double(done - first) : 0.0);
  if (interrupted) {
    std::fflush(stdout);
    std::fprintf(stderr, "dvisim: interrupted by a signal after step %lld of %lld; the results so far are in %s/\n",
                 (long long)done, (long long)steps, rd->out().c_str());
  }
  return code;
}
