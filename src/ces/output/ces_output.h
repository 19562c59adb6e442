// CES outputs beyond the generic ones (output.h): ParaView frames of the particles with per-particle
// material, kind, shape, status and charge; the machine's geometry (machine.vtp); per-particle and
// collection CSVs; the plots (an embedded Python/matplotlib script written next to the results).
#pragma once

#include <string>
#include <vector>

#include "ces/machine.h"
#include "chrono_like/io/output.h"

namespace dvi {
namespace ces {

// VTK XML PolyData of every particle (machine parts excluded): points = centres; point data id (body),
// material, kind (0 metal, 1 plastic, 2 middling), shape, status (1 in flight, 2 collected, 3 lost),
// charge (C), radius (volume-equivalent, m), velocity.
std::string cesVtpFrame(const CesMachine& m);

// The drum, brush and electrodes as closed 48-sided prisms along z, the collection plane as a quad.
std::string cesMachineVtp(const CesMachine& m);

// frame_NNNN.vtp (cesVtpFrame) + frames.pvd, through the shared PvdSeries (chrono_like/io/output.h).
class CesFrameWriter {
 public:
  explicit CesFrameWriter(std::string dir) : series_(std::move(dir)) {}
  void write(double time, const CesMachine& m) { series_.add(time, cesVtpFrame(m)); }
  int count() const { return series_.count(); }

 private:
  PvdSeries series_;
};

// One row per particle: body, material, kind, shape, mass_kg, radius_m, status, charge_C, x, y, z, metal_fraction
// (the metal's volume fraction: a composite's, 1 for a metal, 0 for the others; columns are only ever appended).
std::string cesParticlesCsv(const CesMachine& m);
// One row per collected particle: body, material, kind, mass_kg, x_mm (from collection.x0), z_mm, t_s.
std::string cesCollectedCsv(const CesMachine& m);

// The plot script (writes distribution.png and splitters.png from the CSVs and summary.json in DIR).
const char* cesPlotScript();
// Writes DIR/plot_ces.py and runs it with python3. Returns "" on success, else a one-line reason
// (python3 or matplotlib missing, script failure).
std::string cesMakePlots(const std::string& dir);

}  // namespace ces
}  // namespace dvi
