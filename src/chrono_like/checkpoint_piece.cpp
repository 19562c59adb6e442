#include "chrono_like/checkpoint_piece.h"

#include <cmath>
#include <cstring>

#include "chrono_like/base/errors.h"
#include "chrono_like/base/checksum.h"

namespace dvi {

namespace {

template <class T>
void put(std::string& out, const T& v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof(T));
}

// Reads plain values from the checked bytes; a read past the end is a truncated file.
struct Reader {
  const std::string& b;
  size_t at;
  size_t end;
  const std::string& what;
  template <class T>
  T get() {
    if (end - at < sizeof(T)) throw InputError(what + ": truncated");
    T v;
    std::memcpy(&v, b.data() + at, sizeof(T));
    at += sizeof(T);
    return v;
  }
};

bool finite3(Vec3 v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

void readBodies(Reader& r, CheckpointPiece& p, size_t bodies) {
  const uint64_t n = r.get<uint64_t>();
  const size_t rec = sizeof(int32_t) + 13 * sizeof(real);
  if (n > (r.end - r.at) / rec) throw InputError(r.what + ": " + std::to_string(n) + " bodies do not fit the file");
  for (uint64_t i = 0; i < n; ++i) {
    const int32_t id = r.get<int32_t>();
    MotionState s;
    real v[13];
    for (real& x : v) x = r.get<real>();
    s.pos = Vec3{v[0], v[1], v[2]};
    s.rot = Quat{v[3], v[4], v[5], v[6]};
    s.vel = Vec3{v[7], v[8], v[9]};
    s.omega = Vec3{v[10], v[11], v[12]};
    if (id < 0 || size_t(id) >= bodies || (!p.ids.empty() && id <= p.ids.back()))
      throw InputError(r.what + ": body id " + std::to_string(id) + " out of range or out of order (" +
                       std::to_string(bodies) + " bodies)");
    const double qn =
        double(s.rot.w) * s.rot.w + double(s.rot.x) * s.rot.x + double(s.rot.y) * s.rot.y + double(s.rot.z) * s.rot.z;
    if (!finite3(s.pos) || !finite3(s.vel) || !finite3(s.omega) || !(std::fabs(qn - 1) < 1e-6))
      throw InputError(r.what + ": body " + std::to_string(id) + ": a non-finite state or a rotation of norm != 1");
    p.ids.push_back(id);
    p.states.push_back(s);
  }
}

void readImpulses(Reader& r, CheckpointPiece& p, size_t bodies) {
  const uint64_t n = r.get<uint64_t>();
  const bool normals = p.format >= 2;
  const size_t rec = sizeof(uint64_t) + 2 * sizeof(int32_t) + (normals ? 6 : 3) * sizeof(real);
  if (n > (r.end - r.at) / rec) throw InputError(r.what + ": " + std::to_string(n) + " contacts do not fit the file");
  for (uint64_t i = 0; i < n; ++i) {
    ContactImpulse c;
    c.key = r.get<uint64_t>();
    c.body_a = r.get<int32_t>();
    c.body_b = r.get<int32_t>();
    for (real& g : c.gamma) g = r.get<real>();
    c.normal = Vec3{0, 0, 0};
    if (normals) {
      c.normal.x = r.get<real>();
      c.normal.y = r.get<real>();
      c.normal.z = r.get<real>();
      if (!std::isfinite(c.normal.x) || !std::isfinite(c.normal.y) || !std::isfinite(c.normal.z))
        throw InputError(r.what + ": contact " + std::to_string(i) + ": non-finite normal");
    }
    if (c.body_a < 0 || c.body_b < 0 || size_t(c.body_a) >= bodies || size_t(c.body_b) >= bodies)
      throw InputError(r.what + ": contact " + std::to_string(i) + ": body out of range");
    if (!std::isfinite(c.gamma[0]) || !std::isfinite(c.gamma[1]) || !std::isfinite(c.gamma[2]))
      throw InputError(r.what + ": contact " + std::to_string(i) + ": non-finite impulse");
    p.impulses.push_back(c);
  }
}

}  // namespace

std::string encodePiece(const CheckpointPiece& p) {
  std::string out(p.format >= 2 ? kMpiCheckpointMagic : kMpiCheckpointMagicV1, 8);
  put(out, uint64_t(p.ids.size()));
  for (size_t i = 0; i < p.ids.size(); ++i) {
    const MotionState& s = p.states[i];
    put(out, p.ids[i]);
    for (real v : {s.pos.x, s.pos.y, s.pos.z, s.rot.w, s.rot.x, s.rot.y, s.rot.z, s.vel.x, s.vel.y, s.vel.z, s.omega.x,
                   s.omega.y, s.omega.z})
      put(out, v);
  }
  put(out, uint64_t(p.impulses.size()));
  for (const ContactImpulse& c : p.impulses) {
    put(out, c.key);
    put(out, c.body_a);
    put(out, c.body_b);
    for (real g : c.gamma) put(out, g);
    if (p.format >= 2)
      for (real v : {c.normal.x, c.normal.y, c.normal.z}) put(out, v);
  }
  put(out, fnv1a64(out.data(), out.size()));
  return out;
}

CheckpointPiece decodePiece(const std::string& bytes, const std::string& what, size_t bodies) {
  const bool v2 = bytes.size() >= 8 && bytes.compare(0, 8, kMpiCheckpointMagic, 8) == 0;
  const bool v1 = bytes.size() >= 8 && bytes.compare(0, 8, kMpiCheckpointMagicV1, 8) == 0;
  if (bytes.size() < 8 + 3 * sizeof(uint64_t) || !(v1 || v2))
    throw InputError(what + ": not a dvisim MPI checkpoint piece (" + kMpiCheckpointMagic + " or " +
                     kMpiCheckpointMagicV1 + ")");
  const size_t body_end = bytes.size() - sizeof(uint64_t);
  uint64_t stored = 0;
  std::memcpy(&stored, bytes.data() + body_end, sizeof stored);
  if (stored != fnv1a64(bytes.data(), body_end)) throw InputError(what + ": checksum mismatch (damaged or edited)");
  Reader r{bytes, 8, body_end, what};
  CheckpointPiece p;
  p.format = v2 ? 2 : 1;
  readBodies(r, p, bodies);
  readImpulses(r, p, bodies);
  if (r.at != r.end) throw InputError(what + ": " + std::to_string(r.end - r.at) + " bytes after the contacts");
  return p;
}

}  // namespace dvi
