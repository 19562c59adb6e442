#include "chrono_like/io/output.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <stdexcept>

#include "chrono_like/base/errors.h"

namespace dvi {

void appendNumber(std::string& out, double x, int digits) {
  char buf[48];
  if (!std::isfinite(x)) x = std::isnan(x) ? 0.0 : (x > 0 ? 1e308 : -1e308);  // VTK and CSV readers want numbers
  std::snprintf(buf, sizeof buf, "%.*g", digits, x);
  out += buf;
}

void appendVec3Line(std::string& out, const Vec3& v, int digits) {
  appendNumber(out, v.x, digits);
  out += ' ';
  appendNumber(out, v.y, digits);
  out += ' ';
  appendNumber(out, v.z, digits);
  out += '\n';
}

namespace {

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

std::string shellQuote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

std::string pythonWithMatplotlib() {
  for (const char* p : {"python3", "/usr/bin/python3"})
    if (std::system((std::string(p) + " -c 'import matplotlib' >/dev/null 2>&1").c_str()) == 0) return p;
  return "";
}

void writeFileAtomic(const std::string& path, const std::string& content, Durability d) {
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  std::FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) throw std::runtime_error("cannot write " + tmp + ": " + std::strerror(errno));
  const size_t n = std::fwrite(content.data(), 1, content.size(), f);
  bool ok = n == content.size() && std::fflush(f) == 0;
  if (ok && d == Durability::Synced) ok = ::fsync(::fileno(f)) == 0;
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
  if (d == Durability::Synced) {
    const std::string parent = std::filesystem::path(path).parent_path().string();
    syncDirectory(parent.empty() ? "." : parent);
  }
}

void syncDirectory(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (fd < 0) throw std::runtime_error("cannot open " + dir + ": " + std::strerror(errno));
  const int r = ::fsync(fd);
  const int e = errno;
  ::close(fd);
  if (r != 0) throw std::runtime_error("cannot sync " + dir + ": " + std::strerror(e));
}

std::string bodiesCsv(const std::vector<BodyState>& bodies) {
  std::string out = "id,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz\n";
  out.reserve(out.size() + bodies.size() * 14 * 24);
  for (size_t i = 0; i < bodies.size(); ++i) {
    const BodyState& b = bodies[i];
    out += std::to_string(i);
    const double v[13] = {b.pos.x, b.pos.y, b.pos.z, b.rot.w,   b.rot.x,   b.rot.y,  b.rot.z,
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

std::string vtpFrame(const std::vector<BodyState>& bodies, const std::vector<int64_t>* ids) {
  if (ids && ids->size() != bodies.size())
    throw std::invalid_argument("vtpFrame: " + std::to_string(ids->size()) + " ids for " +
                                std::to_string(bodies.size()) + " bodies");
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
    for (const BodyState& b : bodies) { appendVec3Line(o, get(b)); }
    o += "</DataArray>\n";
  };
  o += "<DataArray type=\"Int64\" Name=\"id\" format=\"ascii\">\n";
  for (size_t i = 0; i < n; ++i)
    o += std::to_string(ids ? (*ids)[i] : int64_t(i)) + (i + 1 == n || i % 16 == 15 ? "\n" : " ");
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

std::string pvtpFrame(const std::vector<std::string>& pieces) {
  std::string o =
      "<?xml version=\"1.0\"?>\n<VTKFile type=\"PPolyData\" version=\"0.1\" byte_order=\"LittleEndian\">\n"
      "<PPolyData GhostLevel=\"0\">\n<PPointData Scalars=\"size\" Vectors=\"velocity\">\n"
      "<PDataArray type=\"Int64\" Name=\"id\"/>\n<PDataArray type=\"Float64\" Name=\"size\"/>\n"
      "<PDataArray type=\"Float64\" Name=\"velocity\" NumberOfComponents=\"3\"/>\n"
      "<PDataArray type=\"Float64\" Name=\"angular_velocity\" NumberOfComponents=\"3\"/>\n"
      "<PDataArray type=\"Float64\" Name=\"orientation\" NumberOfComponents=\"4\"/>\n</PPointData>\n"
      "<PPoints>\n<PDataArray type=\"Float64\" Name=\"position\" NumberOfComponents=\"3\"/>\n</PPoints>\n";
  for (const std::string& p : pieces) o += "<Piece Source=\"" + xmlEscape(p) + "\"/>\n";
  o += "</PPolyData>\n</VTKFile>\n";
  return o;
}

namespace {
const char kPvdHead[] =
    "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" "
    "byte_order=\"LittleEndian\">\n<Collection>\n";
const char kPvdTail[] = "</Collection>\n</VTKFile>\n";
}  // namespace

PvdSeries::~PvdSeries() {
  if (pvd_) std::fclose(pvd_);
}

void PvdSeries::add(double time, const std::string& vtp) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%04d.vtp", count_);
  addFile(time, name, vtp);
}

void PvdSeries::addFile(double time, const std::string& name, const std::string& content) {
  writeFileAtomic(dir_ + "/" + name, content);
  const std::string path = dir_ + "/frames.pvd";
  if (!pvd_) {
    pvd_ = std::fopen(path.c_str(), "wb");
    if (!pvd_ || std::fputs(kPvdHead, pvd_) == EOF)
      throw std::runtime_error("cannot write " + path + ": " + std::strerror(errno));
    body_end_ = std::ftell(pvd_);
  }
  std::string line = "<DataSet timestep=\"";
  appendNumber(line, time);
  line += "\" group=\"\" part=\"0\" file=\"" + xmlEscape(name) + "\"/>\n";
  // The new entry over the old closing tags, then the closing tags: the file is a complete collection after each frame.
  if (std::fseek(pvd_, body_end_, SEEK_SET) != 0 || std::fputs(line.c_str(), pvd_) == EOF)
    throw std::runtime_error("cannot write " + path + ": " + std::strerror(errno));
  body_end_ = std::ftell(pvd_);
  if (std::fputs(kPvdTail, pvd_) == EOF || std::fflush(pvd_) != 0)
    throw std::runtime_error("cannot write " + path + ": " + std::strerror(errno));
  ++count_;
}

ResultDir::ResultDir(const std::string& out) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::path target = fs::absolute(fs::path(out), ec).lexically_normal();
  if (ec || out.empty()) throw InputError("--out '" + out + "': not a usable path");
  if (!target.has_filename()) target = target.parent_path();  // "dir/" -> "dir"
  if (fs::is_symlink(target, ec)) {
    // a link to the results directory: the directory it names is replaced, the link stays
    const fs::path real = fs::canonical(target, ec);
    if (ec) throw InputError("--out " + out + ": a link to nowhere (" + ec.message() + ")");
    target = real;
  }
  if (fs::exists(target, ec) && !fs::is_directory(target, ec))
    throw InputError("--out " + out + ": exists and is not a directory");
  const fs::path parent = target.parent_path();
  fs::create_directories(parent, ec);
  if (ec || !fs::is_directory(parent)) {
    throw InputError("--out " + out + ": cannot create the output directory" + (ec ? " (" + ec.message() + ")" : ""));
  }
  static int serial = 0;
  for (int attempt = 0;; ++attempt) {
    const fs::path tmp = parent / ("." + target.filename().string() + ".tmp-" + std::to_string(::getpid()) + "-" +
                                   std::to_string(serial++));
    if (::mkdir(tmp.c_str(), 0777) == 0) {
      tmp_ = tmp.string();
      break;
    }
    if (errno != EEXIST || attempt > 100)
      throw InputError("--out " + out + ": cannot create a directory beside it (" + std::strerror(errno) + ")");
  }
  out_ = target.string();
}

ResultDir::~ResultDir() {
  if (committed_ || tmp_.empty()) return;
  std::error_code ec;
  std::filesystem::remove_all(tmp_, ec);
}

void ResultDir::commit() {
  namespace fs = std::filesystem;
  if (committed_) return;
  std::error_code ec;
  if (!fs::exists(out_, ec)) {
    if (std::rename(tmp_.c_str(), out_.c_str()) != 0)
      throw std::runtime_error("cannot rename " + tmp_ + " to " + out_ + ": " + std::strerror(errno));
  } else if (::renameat2(AT_FDCWD, tmp_.c_str(), AT_FDCWD, out_.c_str(), RENAME_EXCHANGE) == 0) {
    fs::remove_all(tmp_, ec);  // the previous results, now under the temporary name
  } else {
    // No RENAME_EXCHANGE on this file system: the previous results aside, the new ones in, the previous deleted.
    const std::string old = tmp_ + ".old";
    if (std::rename(out_.c_str(), old.c_str()) != 0)
      throw std::runtime_error("cannot rename " + out_ + " to " + old + ": " + std::strerror(errno));
    if (std::rename(tmp_.c_str(), out_.c_str()) != 0) {
      const int e = errno;
      std::rename(old.c_str(), out_.c_str());
      throw std::runtime_error("cannot rename " + tmp_ + " to " + out_ + ": " + std::strerror(e));
    }
    fs::remove_all(old, ec);
  }
  committed_ = true;
}

}  // namespace dvi
