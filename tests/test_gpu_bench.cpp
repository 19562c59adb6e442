// GPU scaling benchmark (issue 3), kept out of the default test run by Catch2's hidden tag: run it with
//   dvisim_tests "[gpu_bench]"      (env DVISIM_BENCH_OUT=DIR, DVISIM_BENCH_SIZES=10000,100000,...)
// A pile of N spheres (r = 1 cm, mu = 0.5, h = 1e-3 s, APGD 50 iterations) on a lattice that starts in contact;
// the GPU system for every N, our CPU backend for N <= 100k, side by side in one run. It writes
// gpu_scaling_<date>.csv and .md (device, commit, date, ms per step by stage, contacts, device memory, the
// solve's achieved bandwidth against the device copy bandwidth it measures itself).
#include <catch2/catch.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "chrono_like/gpu_factory.h"
#include "chrono_like/system.h"
#if defined(DVISIM_HAVE_CUDA)
#include "gpu/gpu_system.h"
#endif

using namespace dvi;

#if defined(DVISIM_HAVE_CUDA)
namespace dvi::gpu {
double measureCopyBandwidth(size_t bytes);  // gpu_bench_support.cu
}
#endif

namespace {

void spherePile(System& sys, int n) {
  BodyDesc g;
  g.mass = 0;
  g.flags = kBodyFixed;
  g.friction = real(0.5);
  g.shapes.push_back(makePlane(Vec3{0, 1, 0}, 0));
  sys.addBody(g);
  const real r = real(0.01);
  const int side = std::max(1, int(std::cbrt(double(n) / 2)));
  const real d = real(1.98) * r;
  uint32_t h = 12345;
  auto rnd = [&] {
    h = h * 1664525u + 1013904223u;
    return real((h >> 8) * (1.0 / 16777216.0) - 0.5);
  };
  BodyDesc b;
  const real m = real(2500) * real(4.0 / 3.0 * M_PI) * r * r * r;
  b.mass = m;
  b.inertia = Vec3{real(0.4) * m * r * r, real(0.4) * m * r * r, real(0.4) * m * r * r};
  b.friction = real(0.5);
  b.shapes.push_back(makeSphere(r));
  for (int i = 0; i < n; ++i) {
    const int ix = i % side, iz = (i / side) % side, iy = i / (side * side);
    b.pos = Vec3{ix * d + real(0.02) * r * rnd(), r + iy * d, iz * d + real(0.02) * r * rnd()};
    sys.addBody(b);
  }
}

std::string shell(const char* cmd) {
  std::string out;
  if (FILE* f = popen(cmd, "r")) {
    char buf[256];
    while (fgets(buf, sizeof buf, f)) out += buf;
    pclose(f);
  }
  while (!out.empty() && (out.back() == '\n' || out.back() == ' ')) out.pop_back();
  return out;
}

struct Row {
  std::string backend;
  int n = 0;
  double ms = 0;
  double stage_ms[kStageCount] = {};
  double contacts = 0, iterations = 0;
  double device_mib = 0;
  double solve_gbs = 0;
};

Row measure(System& sys, const std::string& backend, int n, int warm, int steps) {
  for (int s = 0; s < warm; ++s) sys.step();
  Row r;
  r.backend = backend;
  r.n = n;
  const auto t0 = std::chrono::steady_clock::now();
  for (int s = 0; s < steps; ++s) {
    sys.step();
    const StepStats& st = sys.lastStats();
    for (int k = 0; k < kStageCount; ++k) r.stage_ms[k] += st.stage_seconds[k] * 1e3 / steps;
    r.contacts += double(st.contacts) / steps;
    r.iterations += double(st.iterations) / steps;
  }
  r.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / steps;
  // bytes one matrix-free iteration must move (contact_problem.h's layout): about 200 B per contact and
  // 50 B per body; APGD does about one Schur product plus two fused vector passes per iteration
  const double iter_bytes = r.contacts * 200.0 + double(n) * 50.0;
  const double solve_s = r.stage_ms[int(StageType::Solve)] * 1e-3;
  if (solve_s > 0 && r.iterations > 0) r.solve_gbs = iter_bytes * r.iterations / solve_s * 1e-9;
#if defined(DVISIM_HAVE_CUDA)
  if (auto* g = dynamic_cast<GpuSystem*>(&sys)) r.device_mib = double(g->deviceBytes()) / (1 << 20);
#endif
  return r;
}

}  // namespace

TEST_CASE("GPU scaling benchmark: sphere pile, GPU vs CPU backend", "[.][gpu_bench]") {
  std::string why;
  if (!gpuAvailable(&why)) {
    WARN("no CUDA device: skipping (" << why << ")");
    return;
  }
#if defined(DVISIM_HAVE_CUDA)
  std::vector<int> sizes = {10000, 100000, 1000000};
  if (const char* e = std::getenv("DVISIM_BENCH_SIZES")) {
    sizes.clear();
    std::stringstream ss(e);
    std::string tok;
    while (std::getline(ss, tok, ',')) sizes.push_back(std::stoi(tok));
  }
  const int cpu_max = std::getenv("DVISIM_BENCH_CPU_MAX") ? std::atoi(std::getenv("DVISIM_BENCH_CPU_MAX")) : 100000;
  const std::string out_dir = std::getenv("DVISIM_BENCH_OUT") ? std::getenv("DVISIM_BENCH_OUT")
                                                               : std::string(DVISIM_SOURCE_DIR) + "/bench/results";
  const double copy_gbs = gpu::measureCopyBandwidth(size_t(1) << 31);
  SystemConfig cfg;
  cfg.dt = real(1e-3);
  cfg.solver = SolverType::APGD;
  cfg.solver_settings.max_iterations = 50;
  std::vector<Row> rows;
  std::string device;
  for (int n : sizes) {
    {
      auto gpu = makeGpuSystem(cfg);
      device = gpu->deviceName();
      spherePile(*gpu, n);
      rows.push_back(measure(*gpu, "gpu", n, 3, 10));
    }
    if (n <= cpu_max) {
      System cpu(cfg);
      spherePile(cpu, n);
      rows.push_back(measure(cpu, "cpu", n, 1, n >= 100000 ? 2 : 5));
    }
  }
  const std::string date = shell("date -u +%Y-%m-%dT%H:%M:%SZ");
  const std::string day = shell("date -u +%Y%m%d-%H%M%S");
  std::string commit = std::getenv("DVISIM_COMMIT") ? std::getenv("DVISIM_COMMIT") : "";
  if (commit.empty()) commit = shell(("git -C " + std::string(DVISIM_SOURCE_DIR) + " rev-parse --short HEAD 2>/dev/null").c_str());
  if (commit.empty()) commit = "unknown";
  const std::string cpu_name = System(cfg).deviceName();
  std::ostringstream md, csv;
  csv << "backend,n,ms_per_step";
  for (int k = 0; k < kStageCount; ++k) csv << ",ms_" << stageName(StageType(k));
  csv << ",contacts,iterations,device_mib,solve_model_GBps,copy_GBps\n";
  md << "# GPU scaling: sphere pile (r = 1 cm, mu = 0.5, h = 1e-3 s, APGD 50 iterations)\n\n"
     << "- GPU: " << device << "\n- CPU: " << cpu_name << "\n- commit: " << commit << "\n- date: " << date
     << "\n- precision: " << (sizeof(real) == 8 ? "double" : "float")
     << "\n- device copy bandwidth (measured, read + write): " << copy_gbs << " GB/s\n\n"
     << "| backend | N | ms/step | broad | narrow | build | solve | integrate | contacts | device MiB | solve GB/s "
        "(model) | % of copy |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const Row& r : rows) {
    csv << r.backend << "," << r.n << "," << r.ms;
    for (int k = 0; k < kStageCount; ++k) csv << "," << r.stage_ms[k];
    csv << "," << r.contacts << "," << r.iterations << "," << r.device_mib << "," << r.solve_gbs << "," << copy_gbs
        << "\n";
    char line[512];
    const double* s = r.stage_ms;
    std::snprintf(line, sizeof line, "| %s | %d | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f | %.0f | %.0f | %.1f | %.1f%% |\n",
                  r.backend.c_str(), r.n, r.ms, s[int(StageType::ComputeAabbs)] + s[int(StageType::BroadPhase)],
                  s[int(StageType::NarrowPhase)], s[int(StageType::BuildRows)] + s[int(StageType::WarmStart)],
                  s[int(StageType::Solve)],
                  s[int(StageType::IntegrateForces)] + s[int(StageType::IntegrateVelocities)] +
                      s[int(StageType::IntegratePositions)],
                  r.contacts, r.device_mib, r.solve_gbs, r.backend == "gpu" ? 100.0 * r.solve_gbs / copy_gbs : 0.0);
    md << line;
  }
  md << "\nThe solve bandwidth is a model: (contacts x 200 B + bodies x 50 B) per iteration over the Solve stage "
        "time, the bytes one matrix-free iteration must move (contact_problem.h). CPU rows: wall time of the "
        "stages on the host CPU above, same run.\n";
  std::printf("%s", md.str().c_str());
  std::ofstream(out_dir + "/gpu_scaling_" + day + ".csv") << csv.str();
  std::ofstream(out_dir + "/gpu_scaling_" + day + ".md") << md.str();
  SUCCEED();
#endif
}
