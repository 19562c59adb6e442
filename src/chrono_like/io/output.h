// Run outputs: summary.json, bodies.csv, VTK PolyData frames (frame_NNNN.vtp) and their ParaView
// collection (frames.pvd). Every file is written to a temporary name in the same directory and renamed
// into place, so a failure never leaves a half-written file nor destroys one written before; a whole run's
// directory is replaced the same way (ResultDir).
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "chrono_like/base/math.h"
#include "chrono_like/system.h"

namespace dvi {

// State of one rigid body at the end of a run or at a frame, in scene order.
struct BodyState {
  Vec3 pos{0, 0, 0};
  Quat rot{1, 0, 0, 0};
  Vec3 vel{0, 0, 0};
  Vec3 omega{0, 0, 0};
  real size = 0;  // characteristic length (smallest half-dimension; radius of a sphere)
};

// Writes `content` to `path` atomically (temporary file + rename). Throws std::runtime_error on failure.
// Durability::Synced (checkpoints) also flushes the file to the disk (fsync) before the rename and the directory
// after it, so that a power cut after the call returns cannot lose the file or leave a name without its content.
enum class Durability { Renamed, Synced };
void writeFileAtomic(const std::string& path, const std::string& content, Durability d = Durability::Renamed);

// fsync of a directory (its entries: a rename into it made durable). Throws std::runtime_error on failure.
void syncDirectory(const std::string& dir);

// `s` single-quoted for /bin/sh.
std::string shellQuote(const std::string& s);

// A python3 that imports matplotlib, for the plot scripts: the first python3 on the PATH (it may be another
// installation, a virtualenv, than the one Debian's python3-matplotlib belongs to), else /usr/bin/python3;
// "" when neither has it.
std::string pythonWithMatplotlib();

// bodies.csv: header id,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz, one row per body, full precision (%.17g).
// Appends x as text with `digits` significant digits (NaN as 0 and +-inf as +-1e308: VTK and CSV readers want
// numbers), and a vector as "x y z" and a newline.
void appendNumber(std::string& out, double x, int digits = 17);
void appendVec3Line(std::string& out, const Vec3& v, int digits = 17);

std::string bodiesCsv(const std::vector<BodyState>& bodies);
void writeBodiesCsv(const std::string& path, const std::vector<BodyState>& bodies);

// One VTK XML PolyData file (ASCII): points = body positions, one vertex cell per body; point data:
// id, size (radius), velocity, angular_velocity, orientation (quaternion w,x,y,z). The ids are the bodies' positions
// in `bodies`, or `ids` (one per body) where given: a piece of a parallel frame holds some of the bodies.
std::string vtpFrame(const std::vector<BodyState>& bodies, const std::vector<int64_t>* ids = nullptr);

// The parallel frame (VTK XML PPolyData, .pvtp) made of the vtpFrame pieces named in `pieces` (file names relative
// to the .pvtp's directory), each holding some of the bodies.
std::string pvtpFrame(const std::vector<std::string>& pieces);

// frames.pvd, the time series ParaView opens, kept valid after every frame in linear time: the file stays open, and
// each frame writes its <DataSet> line over the closing tags and the closing tags after it (one seek and two
// short writes), instead of rewriting the whole collection (quadratic in the frames). Shared by FrameWriter and
// the CES frames (ces_output.h).
class PvdSeries {
 public:
  explicit PvdSeries(std::string dir) : dir_(std::move(dir)) {}
  ~PvdSeries();
  PvdSeries(const PvdSeries&) = delete;
  PvdSeries& operator=(const PvdSeries&) = delete;
  // Writes dir/frame_<index>.vtp (index zero-padded to 4 digits) with `vtp` and adds it to dir/frames.pvd.
  void add(double time, const std::string& vtp);
  // Writes dir/<name> with `content` (e.g. a .pvtp whose pieces are written elsewhere) and adds it to frames.pvd.
  void addFile(double time, const std::string& name, const std::string& content);
  int count() const { return count_; }

 private:
  std::string dir_;
  std::FILE* pvd_ = nullptr;
  long body_end_ = 0;  // offset of the closing tags
  int count_ = 0;
};

// Writes frames of body states into a directory (frame_NNNN.vtp + frames.pvd, PvdSeries).
class FrameWriter {
 public:
  explicit FrameWriter(std::string dir) : series_(std::move(dir)) {}
  void write(double time, const std::vector<BodyState>& bodies) { series_.add(time, vtpFrame(bodies)); }
  int count() const { return series_.count(); }

 private:
  PvdSeries series_;
};

// The results directory of a run, replaced atomically: the run writes into a fresh temporary directory beside
// `out` (path()), and commit() puts it in place of `out` in one rename (renameat2 RENAME_EXCHANGE; where the
// file system lacks it, two renames) and deletes the previous results. Without commit() (the run failed before
// it had anything to write) the destructor deletes the temporary directory and `out` stays as it was. So an
// interrupted or failed run leaves either the previous results untouched or a complete new set, never old files
// (frames of a longer run) beside new ones. Throws InputError when `out` is not a directory or cannot be made.
class ResultDir {
 public:
  explicit ResultDir(const std::string& out);
  ~ResultDir();
  ResultDir(const ResultDir&) = delete;
  ResultDir& operator=(const ResultDir&) = delete;
  const std::string& path() const { return tmp_; }  // where the run writes
  const std::string& out() const { return out_; }
  void commit();
  bool committed() const { return committed_; }

 private:
  std::string out_, tmp_;
  bool committed_ = false;
};

// summary.json, pretty-printed. Inline, so that no nlohmann::json crosses the library boundary (its
// ABI tag changes with the header version a consumer happens to include).
inline void writeSummary(const std::string& path, const nlohmann::json& summary) {
  writeFileAtomic(path, summary.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
}

// The stages of a run in summary.json (docs/MODEL.md §6: "the run summary lists the stages that ran"):
//   stages            the StageType names that ran in at least one step, in step order
//   stage_seconds     their total wall time
//   stage_parts       the StagePart names ("Stage.Part") that ran in at least one step
//   stages_left_out   [{name, reason}] for every stage and part that ran in no step
//   normal_only_steps steps whose CCP had the normal rows only (no contact with mu > 0)
//   pairs_reused_steps steps whose BroadPhase kept the last step's pairs (BroadPhaseSettings::pair_margin)
inline void addStageSummary(nlohmann::json& summary, const StageLog& log) {
  summary["stages"] = nlohmann::json::array();
  summary["stage_seconds"] = nlohmann::json::object();
  summary["stage_parts"] = nlohmann::json::array();
  summary["stages_left_out"] = nlohmann::json::array();
  for (int i = 0; i < kStageCount; ++i) {
    const char* name = stageName(StageType(i));
    if (log.ran[size_t(i)]) {
      summary["stages"].push_back(name);
      summary["stage_seconds"][name] = log.seconds[size_t(i)];
    } else {
      const char* why = log.reason[size_t(i)];
      summary["stages_left_out"].push_back({{"name", name}, {"reason", why ? why : "not run"}});
    }
  }
  for (int i = 0; i < kStagePartCount; ++i) {
    const char* name = stagePartName(StagePart(i));
    if (log.part_ran[size_t(i)]) {
      summary["stage_parts"].push_back(name);
    } else {
      const char* why = log.part_reason[size_t(i)];
      summary["stages_left_out"].push_back({{"name", name}, {"reason", why ? why : "not run"}});
    }
  }
  summary["normal_only_steps"] = log.normal_only_steps;
  summary["pairs_reused_steps"] = log.pairs_reused_steps;
}

// The solver's convergence over a run in summary.json (residuals are relative: solver.h):
//   tolerance                 the relative residual a step must reach (judgedTolerance: the default one for a
//                             fixed iteration count), max_iterations the cap (or the fixed count)
//   steps_not_converged       steps whose solve ended above it
//   worst_relative_residual   the largest relative residual of any step, worst_residual_step its step index
inline void addConvergenceSummary(nlohmann::json& summary, const ConvergenceLog& log, const SolverSettings& s) {
  summary["tolerance"] = judgedTolerance(s);
  summary["tolerance_stop"] = s.tolerance > 0;
  summary["max_iterations"] = s.max_iterations;
  summary["steps_not_converged"] = log.steps_not_converged;
  summary["worst_relative_residual"] = log.worst_relative_residual;
  summary["worst_residual_step"] = log.worst_step;
}

// The one warning line of a run whose steps missed the tolerance (empty when every step converged). `remedy`
// names the options to change; by default the `dvisim run` flags (a CES run names its own keys).
inline std::string convergenceWarning(const ConvergenceLog& log, const SolverSettings& s,
                                      const std::string& remedy = {}) {
  if (log.steps_not_converged == 0) return {};
  char fix[160];
  std::snprintf(fix, sizeof fix, "raise --max-iterations (now %d)%s", s.max_iterations,
                s.tolerance > 0 ? " or loosen --tolerance" : ", or drop --iterations for the tolerance stop");
  char buf[512];
  std::snprintf(
      buf, sizeof buf,
      "dvisim: warning: the solver missed the tolerance %.3g (relative residual) in %lld of %lld steps (worst "
      "%.3g at step %lld); %s",
      double(judgedTolerance(s)), (long long)log.steps_not_converged, (long long)log.steps,
      double(log.worst_relative_residual), (long long)log.worst_step, remedy.empty() ? fix : remedy.c_str());
  return buf;
}

}  // namespace dvi
