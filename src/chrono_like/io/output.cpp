#include "chrono_like/io/output.h"

#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <stdexcept>

namespace dvi {

namespace {

void appendNumber(std::string& out, double x) {
  char buf[40];
  if (!std::isfinite(x)) x = std::isnan(x) ? 0.0 : (x > 0 ? 1e308 : -1e308);  // VTK and CSV readers want numbers
  std::snprintf(buf, sizeof buf, "%.17g", x);
  out += buf;
}

std::string xmlEscape(const std::string& s) {
  std::string o;
  for (char c : s) {
    switch (c) {
      case '&': o += "&amp;"; break;
      case '<': o += "&lt;"; break;
      case '>': o += "&gt;"; break;
      case '"': o += "&quot;"; break;
      default: o += c;
    }
  }
  return o;
}

}  // namespace

void writeFileAtomic(const std::string& path, const std::string& content) {
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  std::FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) throw std::runtime_error("cannot write " + tmp + ": " + std::strerror(errno));
  const size_t n = std::fwrite(content.data(), 1, content.size(), f);
  const bool ok = n == content.size() && std::fflush(f) == 0;
  const int err = errno;
  if (std::fclose(f) != 0 || !ok) {
    std::remove(tmp.c_str());
    throw std::runtime_error("cannot write " + tmp + ": " + std::strerror(ok ? errno : err));
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const int e = errno;
    std::remove(tmp.c_str());
    throw std::runtime_error("cannot rename " + tmp + " to " + path + ": " + std::strerror(e));
  }
}

std::string bodiesCsv(const std::vector<BodyState>& bodies) {
  std::string out = "id,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz\n";
  out.reserve(out.size() + bodies.size() * 14 * 24);
  for (size_t i = 0; i < bodies.size(); ++i) {
    const BodyState& b = bodies[i];
    out += std::to_string(i);
    const double v[13] = {b.pos.x, b.pos.y, b.pos.z, b.rot.w, b.rot.x, b.rot.y, b.rot.z,
                          b.vel.x, b.vel.y, b.vel.z, b.omega.x, b.omega.y, b.omega.z};
    for (double x : v) {
      out += ',';
      appendNumber(out, x);
    }
    out += '\n';
  }
  return out;
}

void writeBodiesCsv(const std::string& path, const std::vector<BodyState>& bodies) {
  writeFileAtomic(path, bodiesCsv(bodies));
}

std::string vtpFrame(const std::vector<BodyState>& bodies) {
  const size_t n = bodies.size();
  std::string o;
  o.reserve(256 + n * 300);
  o += "<?xml version=\"1.0\"?>\n";
  o += "<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\">\n<PolyData>\n";
  o += "<Piece NumberOfPoints=\"" + std::to_string(n) + "\" NumberOfVerts=\"" + std::to_string(n) +
       "\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">\n";
  o += "<PointData Scalars=\"size\" Vectors=\"velocity\">\n";
  auto vec3Array = [&](const char* name, auto get) {
    o += std::string("<DataArray type=\"Float64\" Name=\"") + name + "\" NumberOfComponents=\"3\" format=\"ascii\">\n";
    for (const BodyState& b : bodies) {
      const Vec3 v = get(b);
      appendNumber(o, v.x);
      o += ' ';
      appendNumber(o, v.y);
      o += ' ';
      appendNumber(o, v.z);
      o += '\n';
    }
    o += "</DataArray>\n";
  };
  o += "<DataArray type=\"Int64\" Name=\"id\" format=\"ascii\">\n";
  for (size_t i = 0; i < n; ++i) o += std::to_string(i) + (i + 1 == n || i % 16 == 15 ? "\n" : " ");
  o += "</DataArray>\n";
  o += "<DataArray type=\"Float64\" Name=\"size\" format=\"ascii\">\n";
  for (size_t i = 0; i < n; ++i) {
    appendNumber(o, bodies[i].size);
    o += '\n';
  }
  o += "</DataArray>\n";
  vec3Array("velocity", [](const BodyState& b) { return b.vel; });
  vec3Array("angular_velocity", [](const BodyState& b) { return b.omega; });
  o += "<DataArray type=\"Float64\" Name=\"orientation\" NumberOfComponents=\"4\" format=\"ascii\">\n";
  for (const BodyState& b : bodies) {
    appendNumber(o, b.rot.w);
    o += ' ';
    appendNumber(o, b.rot.x);
    o += ' ';
    appendNumber(o, b.rot.y);
    o += ' ';
    appendNumber(o, b.rot.z);
    o += '\n';
  }
  o += "</DataArray>\n</PointData>\n";
  o += "<Points>\n";
  vec3Array("position", [](const BodyState& b) { return b.pos; });
  o += "</Points>\n<Verts>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n";
  for (size_t i = 0; i < n; ++i) o += std::to_string(i) + (i + 1 == n || i % 16 == 15 ? "\n" : " ");
  o += "</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n";
  for (size_t i = 0; i < n; ++i) o += std::to_string(i + 1) + (i + 1 == n || i % 16 == 15 ? "\n" : " ");
  o += "</DataArray>\n</Verts>\n</Piece>\n</PolyData>\n</VTKFile>\n";
  return o;
}

void FrameWriter::write(double time, const std::vector<BodyState>& bodies) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%04d.vtp", int(entries_.size()));
  writeFileAtomic(dir_ + "/" + name, vtpFrame(bodies));
  entries_.emplace_back(time, name);
  std::string pvd = "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n<Collection>\n";
  for (const auto& e : entries_) {
    std::string t;
    appendNumber(t, e.first);
    pvd += "<DataSet timestep=\"" + t + "\" group=\"\" part=\"0\" file=\"" + xmlEscape(e.second) + "\"/>\n";
  }
  pvd += "</Collection>\n</VTKFile>\n";
  writeFileAtomic(dir_ + "/frames.pvd", pvd);
}

}  // namespace dvi
