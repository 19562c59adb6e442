// Run outputs: summary.json, bodies.csv, VTK PolyData frames (frame_NNNN.vtp) and their ParaView
// collection (frames.pvd). Every file is written to a temporary name in the same directory and renamed
// into place, so a failure never leaves a half-written file nor destroys one written before.
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "math.h"

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
void writeFileAtomic(const std::string& path, const std::string& content);

// bodies.csv: header id,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz, one row per body, full precision (%.17g).
std::string bodiesCsv(const std::vector<BodyState>& bodies);
void writeBodiesCsv(const std::string& path, const std::vector<BodyState>& bodies);

// One VTK XML PolyData file (ASCII): points = body positions, one vertex cell per body; point data:
// id, size (radius), velocity, angular_velocity, orientation (quaternion w,x,y,z).
std::string vtpFrame(const std::vector<BodyState>& bodies);

// Writes frames into a directory and keeps frames.pvd (the time series ParaView opens) up to date.
class FrameWriter {
 public:
  explicit FrameWriter(std::string dir) : dir_(std::move(dir)) {}
  // Writes frame_<index>.vtp (index zero-padded to 4 digits) and rewrites frames.pvd.
  void write(double time, const std::vector<BodyState>& bodies);
  int count() const { return int(entries_.size()); }

 private:
  std::string dir_;
  std::vector<std::pair<double, std::string>> entries_;
};

// summary.json, pretty-printed. Inline, so that no nlohmann::json crosses the library boundary (its
// ABI tag changes with the header version a consumer happens to include).
inline void writeSummary(const std::string& path, const nlohmann::json& summary) {
  writeFileAtomic(path, summary.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
}

}  // namespace dvi
