// CES outputs (ces_output.h).
#include "ces/output/ces_output.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "chrono_like/io/output.h"

namespace dvi {
namespace ces {

namespace {

void num(std::string& o, double x) { appendNumber(o, x, 9); }

}  // namespace

std::string cesVtpFrame(const CesMachine& m) {
  const BodyArrays& b = m.system().bodies();
  const CesParticles& p = m.particles();
  const size_t first = size_t(m.firstParticleBody()), n = p.count() - first;
  std::string o;
  o.reserve(512 + n * 200);
  o += "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\">\n<PolyData>\n";
  o += "<Piece NumberOfPoints=\"" + std::to_string(n) + "\" NumberOfVerts=\"" + std::to_string(n) +
       "\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">\n<PointData Scalars=\"kind\" "
       "Vectors=\"velocity\">\n";
  auto intArray = [&](const char* name, auto get) {
    o += std::string("<DataArray type=\"Int32\" Name=\"") + name + "\" format=\"ascii\">\n";
    for (size_t k = first; k < p.count(); ++k) o += std::to_string(get(k)) + "\n";
    o += "</DataArray>\n";
  };
  auto realArray = [&](const char* name, auto get) {
    o += std::string("<DataArray type=\"Float64\" Name=\"") + name + "\" format=\"ascii\">\n";
    for (size_t k = first; k < p.count(); ++k) {
      num(o, get(k));
      o += '\n';
    }
    o += "</DataArray>\n";
  };
  auto vecArray = [&](const char* name, const std::vector<Vec3>& v) {
    o += std::string("<DataArray type=\"Float64\" Name=\"") + name + "\" NumberOfComponents=\"3\" format=\"ascii\">\n";
    for (size_t k = first; k < p.count(); ++k) appendVec3Line(o, v[k], 9);
    o += "</DataArray>\n";
  };
  const auto& specs = m.specs();
  intArray("id", [&](size_t k) { return int(k); });
  intArray("material", [&](size_t k) { return int(p.material[k]); });
  intArray("kind", [&](size_t k) { return int(m.config().materials[size_t(p.material[k])].kind); });
  intArray("shape", [&](size_t k) { return int(specs[k - first].shape); });
  intArray("status", [&](size_t k) { return int(p.status[k]); });
  realArray("charge", [&](size_t k) { return double(p.charge[k]); });
  realArray("radius", [&](size_t k) { return double(p.radius[k]); });
  vecArray("velocity", b.vel);
  o += "</PointData>\n<Points>\n";
  vecArray("position", b.pos);
  o += "</Points>\n<Verts>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n";
  for (size_t i = 0; i < n; ++i) o += std::to_string(i) + "\n";
  o += "</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n";
  for (size_t i = 0; i < n; ++i) o += std::to_string(i + 1) + "\n";
  o += "</DataArray>\n</Verts>\n</Piece>\n</PolyData>\n</VTKFile>\n";
  return o;
}

std::string cesMachineVtp(const CesMachine& m) {
  const CesModel& md = m.model();
  const double hw = m.config().drum_width / 2;
  std::vector<CylinderXY> cyl{CylinderXY{md.drum.cx, md.drum.cy, md.drum.R}, md.brush};
  for (int k = 0; k < md.n_electrodes; ++k) cyl.push_back(md.electrodes[k]);
  const int sides = 48;
  std::vector<Vec3> pts;
  std::vector<std::vector<int>> polys;
  std::vector<int> part;
  for (size_t c = 0; c < cyl.size(); ++c) {
    const int base = int(pts.size());
    for (int i = 0; i < sides; ++i) {
      const double a = 2 * 3.14159265358979323846 * i / sides;
      const real x = cyl[c].cx + cyl[c].R * real(std::cos(a)), y = cyl[c].cy + cyl[c].R * real(std::sin(a));
      pts.push_back(Vec3{x, y, real(-hw)});
      pts.push_back(Vec3{x, y, real(hw)});
    }
    for (int i = 0; i < sides; ++i) {
      const int j = (i + 1) % sides;
      polys.push_back({base + 2 * i, base + 2 * j, base + 2 * j + 1, base + 2 * i + 1});
      part.push_back(int(c));
    }
  }
  const real y = real(m.config().collection_y), x0 = real(m.config().collection_x0);
  const int base = int(pts.size());
  for (Vec3 q : {Vec3{x0 - real(0.3), y, real(-hw)}, Vec3{x0 + real(0.5), y, real(-hw)},
                 Vec3{x0 + real(0.5), y, real(hw)}, Vec3{x0 - real(0.3), y, real(hw)}})
    pts.push_back(q);
  polys.push_back({base, base + 1, base + 2, base + 3});
  part.push_back(int(cyl.size()));
  std::string o =
      "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\">\n<PolyData>\n";
  o += "<Piece NumberOfPoints=\"" + std::to_string(pts.size()) +
       "\" NumberOfVerts=\"0\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"" +
       std::to_string(polys.size()) + "\">\n";
  o += "<CellData Scalars=\"part\">\n<DataArray type=\"Int32\" Name=\"part\" format=\"ascii\">\n";
  for (int p : part) o += std::to_string(p) + "\n";
  o += "</DataArray>\n</CellData>\n<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n";
  for (const Vec3& q : pts) appendVec3Line(o, q, 9);
  o += "</DataArray>\n</Points>\n<Polys>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n";
  size_t off = 0;
  std::string offsets;
  for (const auto& poly : polys) {
    for (int i : poly) o += std::to_string(i) + " ";
    o += "\n";
    off += poly.size();
    offsets += std::to_string(off) + "\n";
  }
  o += "</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n" + offsets;
  o += "</DataArray>\n</Polys>\n</Piece>\n</PolyData>\n</VTKFile>\n";
  return o;
}

std::string cesParticlesCsv(const CesMachine& m) {
  const BodyArrays& b = m.system().bodies();
  const CesParticles& p = m.particles();
  const size_t first = size_t(m.firstParticleBody());
  std::string o = "body,material,kind,shape,mass_kg,radius_m,status,charge_C,x,y,z,metal_fraction\n";
  for (size_t k = first; k < p.count(); ++k) {
    const MaterialConfig& mat = m.config().materials[size_t(p.material[k])];
    o += std::to_string(k) + "," + mat.name + "," + materialKindName(mat.kind) + "," +
         particleShapeName(m.specs()[k - first].shape) + ",";
    num(o, double(p.mass_fg[k]) * kFemtogram);
    o += ",";
    num(o, p.radius[k]);
    o += std::string(",") +
         (p.status[k] == kStatusCollected ? "collected"
          : p.status[k] == kStatusLost    ? "lost"
                                          : "in_flight") +
         ",";
    num(o, p.charge[k]);
    for (real c : {b.pos[k].x, b.pos[k].y, b.pos[k].z}) {
      o += ",";
      num(o, c);
    }
    o += ",";
    num(o, m.specs()[k - first].metal_fraction);  // volume fraction (a composite's; 1 metal, 0 the others)
    o += "\n";
  }
  return o;
}

std::string cesCollectedCsv(const CesMachine& m) {
  std::string o = "body,material,kind,mass_kg,x_mm,z_mm,t_s\n";
  for (const CollectedParticle& c : m.collected()) {
    o += std::to_string(c.body) + "," + m.config().materials[size_t(c.material)].name + "," + materialKindName(c.kind) +
         ",";
    num(o, double(c.mass_fg) * kFemtogram);
    o += ",";
    num(o, c.x * 1e3);
    o += ",";
    num(o, c.z * 1e3);
    o += ",";
    num(o, c.t);
    o += "\n";
  }
  return o;
}

namespace {
// The plot script of cesPlotScript: reads summary.json and the CES CSVs of a results directory and writes
// distribution.png, splitters.png and grade_recovery.png (matplotlib).
constexpr const char kCesPlotScript[] = R"PY(#!/usr/bin/env python3
"""dvisim CES plots, written by `dvisim run` next to its results; run again with: python3 plot_ces.py DIR

distribution.png  collected mass per mm along the collection plane for each material kind (the paper's Fig. 5),
                  with the configured splitters
splitters.png     separation score (mean Newton efficiency) over (s1, s2), the best setting, and grade/recovery
                  of metal (conductor bin) and plastic (nonconductor bin) through the best setting
grade_recovery.png the grade-recovery curve of each product and the optimised setting
"""
import csv, json, os, sys

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt

d = sys.argv[1] if len(sys.argv) > 1 else "."
summary = json.load(open(os.path.join(d, "summary.json")))
ces = summary["ces"]
colors = {"metal": "#c0392b", "plastic": "#2471a3", "middling": "#8e8e8e"}

rows = list(csv.DictReader(open(os.path.join(d, "ces_distribution.csv"))))
fig, ax = plt.subplots(figsize=(8, 4.5))
if rows:
    lo = [float(r["x_lo_mm"]) for r in rows]
    width = float(rows[0]["x_hi_mm"]) - lo[0]
    for k in ("metal", "plastic", "middling"):
        y = [float(r[k + "_kg"]) * 1e3 / width for r in rows]  # g per mm
        if any(v > 0 for v in y):
            ax.fill_between(lo + [lo[-1] + width], y + [y[-1]], step="post", alpha=0.35, color=colors[k])
            ax.step(lo + [lo[-1] + width], y + [y[-1]], where="post", color=colors[k], label=k)
for name, s in (("s1", ces["splitters"]["s1_mm"]), ("s2", ces["splitters"]["s2_mm"])):
    ax.axvline(s, color="k", ls="--", lw=1)
    ax.text(s, ax.get_ylim()[1] * 0.95, " " + name, va="top")
ax.set_xlabel("position on the collection plane x' (mm)")
ax.set_ylabel("collected mass (g/mm)")
ax.set_title("CES mass distribution: %.3g g fed, %.3g g collected, %.3g g in flight, %.3g g lost" % (
    ces["fed_mass_kg"] * 1e3, ces["collected_mass_kg"] * 1e3, ces["in_flight_mass_kg"] * 1e3, ces["lost_mass_kg"] * 1e3),
    fontsize=9)
ax.legend()
fig.tight_layout()
fig.savefig(os.path.join(d, "distribution.png"), dpi=120)

cells = list(csv.DictReader(open(os.path.join(d, "ces_splitters.csv"))))
pos = sorted({float(c["s1_mm"]) for c in cells})
index = {p: i for i, p in enumerate(pos)}
n = len(pos)
grid = [[float("nan")] * n for _ in range(n)]
for c in cells:
    grid[index[float(c["s2_mm"])]][index[float(c["s1_mm"])]] = float(c["score"])
best = ces["best"]
fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
step = pos[1] - pos[0] if n > 1 else 1
im = a1.imshow(grid, origin="lower", extent=[pos[0] - step / 2, pos[-1] + step / 2, pos[0] - step / 2, pos[-1] + step / 2],
               cmap="viridis", aspect="auto")
fig.colorbar(im, ax=a1, label="score (mean Newton efficiency)")
a1.plot([best["s1_mm"]], [best["s2_mm"]], "r*", ms=12, label="best")
a1.set_xlabel("s1 (mm)")
a1.set_ylabel("s2 (mm)")
a1.set_title("splitter map (%d x %d positions)" % (n, n), fontsize=9)
a1.legend(loc="lower right")
# the grid positions nearest the best setting (the CSV and the summary round differently)
s1b = min({float(c["s1_mm"]) for c in cells}, key=lambda v: abs(v - best["s1_mm"]))
s2b = min({float(c["s2_mm"]) for c in cells}, key=lambda v: abs(v - best["s2_mm"]))
s2_line = sorted((float(c["s2_mm"]), float(c["grade_metal"]), float(c["recovery_metal"])) for c in cells
                 if float(c["s1_mm"]) == s1b)
s1_line = sorted((float(c["s1_mm"]), float(c["grade_plastic"]), float(c["recovery_plastic"])) for c in cells
                 if float(c["s2_mm"]) == s2b)
if s2_line:
    a2.plot([r[0] for r in s2_line], [r[1] for r in s2_line], color=colors["metal"], label="metal grade (conductor bin) vs s2")
    a2.plot([r[0] for r in s2_line], [r[2] for r in s2_line], color=colors["metal"], ls="--", label="metal recovery vs s2")
if s1_line:
    a2.plot([r[0] for r in s1_line], [r[1] for r in s1_line], color=colors["plastic"], label="plastic grade (nonconductor bin) vs s1")
    a2.plot([r[0] for r in s1_line], [r[2] for r in s1_line], color=colors["plastic"], ls="--", label="plastic recovery vs s1")
a2.set_xlabel("splitter position (mm)")
a2.set_ylim(-0.02, 1.02)
a2.set_title("through the best setting s1 = %.1f mm, s2 = %.1f mm" % (best["s1_mm"], best["s2_mm"]), fontsize=9)
a2.legend(fontsize=7, loc="lower center")
fig.tight_layout()
fig.savefig(os.path.join(d, "splitters.png"), dpi=120)

gr = list(csv.DictReader(open(os.path.join(d, "ces_grade_recovery.csv"))))
fig, ax = plt.subplots(figsize=(6, 5))
for prod, col in (("conductor", colors["metal"]), ("nonconductor", colors["plastic"])):
    pts = [(float(r[prod + "_recovery"]), float(r[prod + "_grade"])) for r in gr if float(r[prod + "_grade"]) > 0]
    if pts:
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", ms=3, color=col, label=prod + " product")
tg = ces.get("grade_targets", {})
for prod, col in (("conductor", colors["metal"]), ("nonconductor", colors["plastic"])):
    if prod in tg:
        ax.axhline(tg[prod], color=col, ls=":", lw=1)
ax.plot([best["recovery_metal"]], [best["grade_metal"]], "*", color=colors["metal"], ms=12)
ax.plot([best["recovery_plastic"]], [best["grade_plastic"]], "*", color=colors["plastic"], ms=12)
ax.set_xlabel("recovery (of the fed mass)")
ax.set_ylabel("grade")
ax.set_title("grade-recovery curves (one splitter swept); stars: the optimised setting", fontsize=9)
ax.legend(fontsize=8)
fig.tight_layout()
fig.savefig(os.path.join(d, "grade_recovery.png"), dpi=120)
)PY";
}  // namespace

const char* cesPlotScript() { return kCesPlotScript; }

std::string cesMakePlots(const std::string& dir) {
  const std::string python = pythonWithMatplotlib();
  if (python.empty())
    return "plots not written: python3 with matplotlib is missing (Debian: apt-get install python3-matplotlib)";
  const std::string script = dir + "/plot_ces.py";
  writeFileAtomic(script, cesPlotScript());
  const std::string cmd =
      python + " " + shellQuote(script) + " " + shellQuote(dir) + " >" + shellQuote(dir + "/plot_ces.log") + " 2>&1";
  if (std::system(cmd.c_str()) != 0) return "plots not written: plot_ces.py failed (see " + dir + "/plot_ces.log)";
  return "";
}

}  // namespace ces
}  // namespace dvi
