// `dvisim run SCENE` over several processes: `mpirun -np K dvisim run SCENE ...` steps a plain (non-CES) scene with
// the domain decomposition (chrono_like/mpi/distributed_system.h); process 0 writes summary.json and bodies.csv,
// every body in scene order. Built where MPI is (DVISIM_HAVE_MPI); the same binary started without mpirun runs as
// before.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace dvi {
class Scene;
struct SystemConfig;
}  // namespace dvi

// MPI_Init when this process was started by mpirun (an Open MPI or PMI launcher's environment), MPI_Finalize at the
// end; nothing otherwise.
class MpiSession {
 public:
  MpiSession(int* argc, char*** argv);
  ~MpiSession();
  MpiSession(const MpiSession&) = delete;
  MpiSession& operator=(const MpiSession&) = delete;
};

// Stops every process of the run with exit code `code` (MPI_Abort): an error on one process ends the run.
void mpiAbort(int code);
// Whether this process runs under mpirun (MPI initialized by MpiSession).
bool mpiInitialized();
// Processes of this run: MPI_COMM_WORLD's size under mpirun, else 1.
int mpiProcesses();
// This process's rank in MPI_COMM_WORLD (0 without mpirun), the processes on its host and its rank among them.
int mpiRank();
int mpiHostProcesses();
int mpiHostRank();
// Waits for every process (nothing without mpirun).
void mpiBarrier();
// Process 0's value on every process.
int mpiBroadcast(int value);
// The concatenation over the processes, in rank order, on process 0 (the others get an empty list).
std::vector<long long> mpiGatherToRoot(const std::vector<long long>& mine);

// The scene's run over mpiProcesses() processes, steps of cfg.step.dt; results into `out` (process 0), with a
// parallel VTK frame (frame_NNNN.pvtp, one frame_NNNN_pR.vtp piece a process, in frames.pvd) before each step
// listed in frame_at (ascending; `steps` for after the last). `backend`: auto or cpu, or gpu (one device a process:
// host rank i on device i mod the devices); the Bullet backend does not run over several processes (InputError).
// Process 0 also writes checkpoint/ (each process's piece of the last state, run_checkpoint.h, and manifest.json);
// `resume` (a results directory with one) starts from it instead, on any number of processes, and runs on to step
// `steps` (InputError where it does not fit: another scene file, dt or body count, a damaged piece).
// With `checkpoint_every` > 0 every process also writes its piece every that many steps, and process 0 puts each
// complete set in place (run_checkpoint.h: Periodic), so that a run killed outright resumes from the newest.
int runSceneMpi(const dvi::Scene& scene, const dvi::SystemConfig& cfg, int64_t steps,
                const std::vector<int64_t>& frame_at, const std::string& out, const std::string& backend,
                const std::string& resume = {}, int64_t checkpoint_every = 0);
