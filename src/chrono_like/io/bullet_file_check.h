// Validation of a .bullet file before Bullet's own parser sees it. Bullet's bFile/btBulletWorldImporter trust
// every count, index, length and pointer in the file: a single flipped bit crashes them (bDNA::init and
// initCmpFlags index arrays with the file's numbers, resolvePointersStructRecursive follows struct members the
// DNA describes, duplicateName runs strlen on whatever a name pointer resolves to, the importer casts shape
// data by a type field and reads as many children or points as a count says).
//
// sanitizeBulletFile() checks the whole structure Bullet will walk and returns a copy of the file that holds
// only what the scene importer needs, every part of it checked:
//   header   "BULLET" f|d, 64-bit pointers ('-'), little endian ('v'), 3 version digits (not the broken 276)
//   blocks   (code, length, old pointer, struct index, count) + data, lengths inside the file and multiples of
//            4, walked the way Bullet walks them up to the DNA block
//   DNA      names, types, type lengths and structs inside the DNA block, every index in range, primitive
//            types of their standard sizes, every struct's length the sum of its members, structs inside
//            structs acyclic, pointers of 8 bytes; where Bullet would copy a block unconverted (its struct
//            equal to Bullet's own), the same member offsets as Bullet's own struct
//   graph    from the rigid bodies (RBDY) and world blocks (DWLD), the blocks they point to: a body's shape
//            (SHAP) and name, a shape's name, a compound's children (ARAY of btCompoundShapeChildData) and
//            their shapes (acyclic, nested at most max_compound_depth), a hull's points, a multi-sphere's
//            spheres; each of the struct the importer casts it to (by the shape type field: only the shape
//            types dvisim imports), holding at least as many elements as its count, names NUL-terminated
//   precision the rigid-body and world structs of the precision the header names (a float file read as
//            double overflows every read of the body)
// Everything else (collision objects, constraints, BVHs, soft bodies, unreachable shapes) is left out of the
// copy: the scene never used it, and Bullet's converters for it are not checked. The copy is laid out so that
// Bullet's scan for the DNA (it looks for the bytes "DNA1"/"SDNANAME" anywhere in the file) finds the DNA
// block; it is checked again on the copy.
//
// Header-only: included by scene.cpp alone (one translation unit), adds no source file to the build lists.
#pragma once

#include <LinearMath/btSerializer.h>

#include <cctype>
#include <cstdint>
#include <cstring>
#include <functional>
#include <algorithm>
#include <map>
#include <set>
#include <unordered_map>
#include <string>
#include <vector>

#include "chrono_like/base/errors.h"

namespace dvi {
namespace bulletfile {

struct Fail {
  std::string origin;
  [[noreturn]] void operator()(const std::string& what) const {
    throw InputError(origin + ": corrupt .bullet file (" + what + ")");
  }
};

inline int32_t rd32(const char* p) {
  int32_t v;
  std::memcpy(&v, p, 4);
  return v;
}
inline int16_t rd16(const char* p) {
  int16_t v;
  std::memcpy(&v, p, 2);
  return v;
}
inline uint64_t rd64(const char* p) {
  uint64_t v;
  std::memcpy(&v, p, 8);
  return v;
}
inline std::string code4(const char* p) {
  std::string s(p, 4);
  for (char& c : s)
    if (c < 32 || c > 126) c = '?';
  return s;
}

// One parsed SDNA (names, types, type lengths, structs), checked as described above.
struct Dna {
  struct Member {
    int type, name;
    int64_t offset, size;
    bool pointer, ptrptr;
    int dims;
  };
  struct Struct {
    int type;
    std::vector<Member> members;
  };
  std::vector<std::string> names, types;
  std::vector<int> tlen;
  std::vector<Struct> structs;
  std::map<int, int> struct_of_type;  // type index -> struct index
  std::map<std::string, int> struct_by_name;
  int first_struct_type = 0;

  int structByName(const std::string& n) const {
    auto it = struct_by_name.find(n);
    return it == struct_by_name.end() ? -1 : it->second;
  }
  const std::string& structName(int s) const { return types[size_t(structs[size_t(s)].type)]; }
  int64_t structLen(int s) const { return tlen[size_t(structs[size_t(s)].type)]; }
  // The member `name` of struct s, or nullptr.
  const Member* member(int s, const char* name) const {
    for (const Member& m : structs[size_t(s)].members)
      if (names[size_t(m.name)] == name) return &m;
    return nullptr;
  }
  // The struct a by-value member is (-1 for primitives and pointers).
  int memberStruct(const Member& m) const {
    if (m.pointer) return -1;
    auto it = struct_of_type.find(m.type);
    return it == struct_of_type.end() ? -1 : it->second;
  }
  // True when struct s is `base` or begins with it (Bullet's C-style inheritance: the base is the first member).
  bool derivesFrom(int s, const std::string& base, int* offset_depth = nullptr) const {
    for (int guard = 0; s >= 0 && guard < 64; ++guard) {
      if (structName(s) == base) return true;
      if (structs[size_t(s)].members.empty()) return false;
      const Member& first = structs[size_t(s)].members[0];
      if (first.offset != 0) return false;
      s = memberStruct(first);
    }
    (void)offset_depth;
    return false;
  }

  // Parses the DNA at [p, end). `base_aligned`: p's address is what Bullet aligns (it aligns absolute addresses
  // to 4); the caller guarantees p is 4-aligned relative to a 4-aligned buffer start.
  void parse(const char* p, const char* end, const Fail& fail, const char* what) {
    const char* const begin = p;
    auto need = [&](int64_t n) {
      if (end - p < n) fail(std::string(what) + " ends early");
    };
    auto align = [&]() {
      const int64_t off = p - begin;
      p += (4 - off % 4) % 4;
    };
    auto tag = [&](const char* t) {
      need(4);
      if (std::memcmp(p, t, 4) != 0) fail(std::string(what) + ": no " + t + " section");
      p += 4;
    };
    tag("SDNA");
    tag("NAME");
    auto count = [&](const char* section) {
      need(4);
      const int32_t n = rd32(p);
      p += 4;
      if (n < 1 || n > 32767)
        fail(std::string(what) + ": " + section + " count " + std::to_string(n) + " out of range");
      return n;
    };
    auto strings = [&](int32_t n, std::vector<std::string>& out, const char* section) {
      for (int32_t i = 0; i < n; ++i) {
        const void* z = std::memchr(p, 0, size_t(end - p));
        if (!z) fail(std::string(what) + ": unterminated " + section + " string");
        const char* e = static_cast<const char*>(z);
        if (e == p) fail(std::string(what) + ": empty " + section + " string");
        out.emplace_back(p, size_t(e - p));
        p = e + 1;
      }
    };
    const int32_t nnames = count("name");
    strings(nnames, names, "name");
    need(1);  // Bullet reads name[1] of the last name
    align();
    tag("TYPE");
    const int32_t ntypes = count("type");
    strings(ntypes, types, "type");
    {
      std::set<std::string> unique(types.begin(), types.end());
      if (unique.size() != types.size()) fail(std::string(what) + ": a type name appears twice");
    }
    align();
    tag("TLEN");
    need(int64_t(ntypes) * 2 + (ntypes & 1) * 2);
    for (int32_t i = 0; i < ntypes; ++i, p += 2) tlen.push_back(rd16(p));
    if (ntypes & 1) p += 2;
    tag("STRC");
    const int32_t nstructs = count("struct");
    for (int32_t i = 0; i < nstructs; ++i) {
      need(4);
      Struct s;
      s.type = rd16(p);
      const int nm = rd16(p + 2);
      p += 4;
      if (s.type < 0 || s.type >= ntypes)
        fail(std::string(what) + ": struct " + std::to_string(i) + " has type index " + std::to_string(s.type) +
             " out of range");
      if (nm < 0 || nm > 4096)
        fail(std::string(what) + ": struct " + std::to_string(i) + " has " + std::to_string(nm) + " members");
      need(int64_t(nm) * 4);
      for (int k = 0; k < nm; ++k, p += 4) {
        Member m{};
        m.type = rd16(p);
        m.name = rd16(p + 2);
        if (m.type < 0 || m.type >= ntypes || m.name < 0 || m.name >= nnames)
          fail(std::string(what) + ": struct " + types[size_t(s.type)] + " has a member index out of range");
        s.members.push_back(m);
      }
      if (!struct_of_type.emplace(s.type, i).second)
        fail(std::string(what) + ": struct " + types[size_t(s.type)] + " defined twice");
      struct_by_name[types[size_t(s.type)]] = i;
      structs.push_back(std::move(s));
    }
    first_struct_type = structs[0].type;
    check(fail, what);
  }

  // Names: "m_x", "*m_p", "**m_pp", "m_a[4]", "m_b[3][4]" (Bullet's name_is_array: a product of at most two
  // decimal dimensions). Sizes: pointers 8 bytes, primitives of their standard size, structs their TLEN; each
  // struct's TLEN the sum of its members; struct members that are structs (type >= the first struct's type,
  // as Bullet decides) really are structs, without cycles.
  void check(const Fail& fail, const char* what) {
    static const std::map<std::string, int> kPrimitive = {{"char", 1},   {"uchar", 1}, {"short", 2}, {"ushort", 2},
                                                          {"int", 4},    {"long", 4},  {"ulong", 4}, {"float", 4},
                                                          {"double", 8}, {"void", 0}};
    for (size_t t = 0; t < types.size(); ++t) {
      if (tlen[t] < 0) fail(std::string(what) + ": type " + types[t] + " has a negative length");
      auto it = kPrimitive.find(types[t]);
      if (it != kPrimitive.end() && tlen[t] != it->second)
        fail(std::string(what) + ": primitive type " + types[t] + " of length " + std::to_string(tlen[t]));
      if (int(t) < first_struct_type && it == kPrimitive.end())
        fail(std::string(what) + ": unknown primitive type " + types[t]);
    }
    if (structByName("ListBase") < 0 || structLen(structByName("ListBase")) != 16)
      fail(std::string(what) + ": no ListBase of two 8-byte pointers");
    std::vector<int> dims(names.size()), ptr(names.size()), pp(names.size());
    for (size_t n = 0; n < names.size(); ++n) {
      const std::string& s = names[n];
      ptr[n] = s[0] == '*' || (s.size() > 1 && s[1] == '*');
      pp[n] = s.size() > 1 && s[0] == '*' && s[1] == '*';
      int64_t d = 1;
      size_t at = s.find('[');
      int ndims = 0;
      while (at != std::string::npos) {
        const size_t close = s.find(']', at);
        if (close == std::string::npos || close == at + 1 || close - at > 7 || ++ndims > 2)
          fail(std::string(what) + ": malformed array name " + s.substr(0, 40));
        int64_t v = 0;
        for (size_t i = at + 1; i < close; ++i) {
          if (s[i] < '0' || s[i] > '9') fail(std::string(what) + ": malformed array name " + s.substr(0, 40));
          v = v * 10 + (s[i] - '0');
        }
        if (v < 1) fail(std::string(what) + ": array of zero length " + s.substr(0, 40));
        d *= v;
        if (close + 1 != s.size() && s[close + 1] != '[')
          fail(std::string(what) + ": malformed array name " + s.substr(0, 40));
        at = close + 1 < s.size() ? close + 1 : std::string::npos;
      }
      if (d > 65536) fail(std::string(what) + ": array " + s.substr(0, 40) + " too long");
      dims[n] = int(d);
    }
    for (Struct& s : structs)
      for (Member& m : s.members) {
        m.pointer = ptr[size_t(m.name)] != 0;
        m.ptrptr = pp[size_t(m.name)] != 0;
        m.dims = dims[size_t(m.name)];
        if (!m.pointer && m.type >= first_struct_type && !struct_of_type.count(m.type))
          fail(std::string(what) + ": member " + names[size_t(m.name)] + " of " + types[size_t(s.type)] +
               " has no struct type");
        m.size = m.pointer ? int64_t(8) * m.dims : int64_t(tlen[size_t(m.type)]) * m.dims;
      }
    // Struct lengths and offsets; cycles of structs inside structs (by value) would make the sum infinite.
    std::vector<int> state(structs.size(), 0);  // 0 new, 1 on the stack, 2 done
    for (size_t i = 0; i < structs.size(); ++i) layout(int(i), state, 0, fail, what);
  }
  void layout(int s, std::vector<int>& state, int depth, const Fail& fail, const char* what) {
    if (state[size_t(s)] == 2) return;
    if (state[size_t(s)] == 1 || depth > 64) fail(std::string(what) + ": struct " + structName(s) + " contains itself");
    state[size_t(s)] = 1;
    int64_t off = 0;
    for (Member& m : structs[size_t(s)].members) {
      const int sub = memberStruct(m);
      if (sub >= 0) layout(sub, state, depth + 1, fail, what);
      m.offset = off;
      off += m.size;
    }
    if (off != structLen(s))
      fail(std::string(what) + ": struct " + structName(s) + " has length " + std::to_string(structLen(s)) +
           " but its members take " + std::to_string(off));
    state[size_t(s)] = 2;
  }
};

// Bullet's bDNA::initCmpFlags: file struct i is copied without conversion when it has the same member types and
// names and the same length as Bullet's own struct i (by index). Then the importer reads it at Bullet's offsets.
inline bool copiedUnconverted(const Dna& file, const Dna& mem, int s) {
  if (size_t(s) >= mem.structs.size()) return false;
  const Dna::Struct& a = file.structs[size_t(s)];
  const Dna::Struct& b = mem.structs[size_t(s)];
  if (a.members.size() != b.members.size() || file.tlen[size_t(a.type)] != mem.tlen[size_t(b.type)]) return false;
  for (size_t k = 0; k < a.members.size(); ++k)
    if (file.types[size_t(a.members[k].type)] != mem.types[size_t(b.members[k].type)] ||
        file.names[size_t(a.members[k].name)] != mem.names[size_t(b.members[k].name)])
      return false;
  return true;
}

// Same member offsets, recursively through struct members, in the file's struct fs and Bullet's struct ms.
inline bool sameLayout(const Dna& file, int fs, const Dna& mem, int ms, int depth = 0) {
  if (depth > 64) return false;
  const Dna::Struct& a = file.structs[size_t(fs)];
  const Dna::Struct& b = mem.structs[size_t(ms)];
  if (a.members.size() != b.members.size() || file.structLen(fs) != mem.structLen(ms)) return false;
  for (size_t k = 0; k < a.members.size(); ++k) {
    const Dna::Member &x = a.members[k], &y = b.members[k];
    if (x.offset != y.offset || x.size != y.size || x.pointer != y.pointer) return false;
    const int sx = file.memberStruct(x), sy = mem.memberStruct(y);
    if ((sx >= 0) != (sy >= 0)) return false;
    if (sx >= 0 && !sameLayout(file, sx, mem, sy, depth + 1)) return false;
  }
  return true;
}

// Bullet's own DNA (64-bit), parsed once.
inline const Dna& memoryDna() {
  static const Dna dna = [] {
    Dna d;
    d.parse(sBulletDNAstr64, sBulletDNAstr64 + sBulletDNAlen64, Fail{"Bullet's built-in DNA"}, "built-in DNA");
    return d;
  }();
  return dna;
}

// Where Bullet's bFile::parseInternal finds the DNA in a buffer of `len` bytes (followed by zero padding): it
// compares every byte position with "REND", "DNA1" (a block header followed by "SDNANAME") and "SDNANAME"; the
// last match wins, and after a "REND" the first position that sets the DNA ends the scan (version 276, which
// also ends it, is refused). Returns the offset of the DNA data, or -1 where Bullet finds none. The same
// decisions, visiting only the positions where one of the three patterns occurs.
inline int64_t bulletDnaScan(const char* buf, int64_t len) {
  // The next position >= from where pat matches, as far as the buffer goes (a prefix at the very end counts:
  // the caller decides what the padding makes of it). memchr for the first byte, then a compare.
  auto next = [&](int64_t from, const char* pat, size_t n) -> int64_t {
    while (from < len) {
      const void* p = std::memchr(buf + from, pat[0], size_t(len - from));
      if (!p) return len;
      const int64_t i = static_cast<const char*>(p) - buf;
      if (std::memcmp(buf + i, pat, std::min<size_t>(n, size_t(len - i))) == 0) return i;
      from = i + 1;
    }
    return len;
  };
  int64_t rend = next(0, "REND", 4), d1 = next(0, "DNA1", 4), sd = next(0, "SDNANAME", 8);
  int64_t dna = -1;
  bool after_rend = false;
  for (;;) {
    const int64_t i = std::min({rend, d1, sd});
    if (i >= len) break;
    // a pattern matched where fewer than its bytes remain compares against the zero padding: no match there
    if (i == rend) {
      if (i + 4 <= len) after_rend = true;
      rend = len;  // only the first REND matters
    }
    if (i == d1) {
      if (i + 4 <= len) {
        const bool sdna = i + 32 <= len && std::memcmp(buf + i + 24, "SDNANAME", 8) == 0;
        const bool len_ok = i + 8 <= len && rd32(buf + i + 4) >= 0;
        dna = sdna && len_ok ? i + 24 : -1;
      }
      d1 = next(i + 1, "DNA1", 4);
    } else if (i == sd) {
      if (i + 8 <= len) dna = i;
    }
    if (i == sd) sd = next(i + 1, "SDNANAME", 8);
    if (after_rend && dna >= 0) break;
  }
  return dna;
}

struct Block {
  int64_t at;  // offset of the block header
  std::string code;
  int32_t len, dna, nr;
  uint64_t old;
};

// The walk of sanitizeBulletFile: one file's blocks, its DNA, and what has been checked and kept so far.
class FileChecker {
 public:
  static constexpr int64_t kHead = 24;                       // a block header's bytes
  static constexpr int64_t kMaxExpanded = int64_t(1) << 24;  // primitives the shapes may expand to

  FileChecker(const std::string& file, const std::string& origin, int max_compound_depth)
      : fail(Fail{origin}),
        origin_(origin),
        max_depth_(max_compound_depth),
        buf_(file.data()),
        size_(int64_t(file.size())) {}

  // The header; returns whether the file is in double precision.
  bool checkHeader() const {
    const char* buf = buf_;
    if (size_ == 0) refuse("file is empty");
    if (size_ < 12 || std::memcmp(buf, "BULLET", 6) != 0) refuse("not a .bullet file (no BULLET header)");
    if (buf[6] != 'f' && buf[6] != 'd') refuse("not a .bullet file (bad precision byte)");
    if (buf[7] != '-' && buf[7] != '_') refuse("not a .bullet file (bad pointer-size byte)");
    if (buf[8] != 'v' && buf[8] != 'V') refuse("not a .bullet file (bad endianness byte)");
    for (int i = 9; i < 12; ++i)
      if (!std::isdigit(static_cast<unsigned char>(buf[i]))) refuse("not a .bullet file (bad version)");
    if (buf[7] == '_')
      refuse("written by a 32-bit program (4-byte pointers): not supported, re-export it from a 64-bit build");
    if (buf[8] == 'V') refuse("big-endian .bullet file: not supported, re-export it on a little-endian machine");
    if (std::memcmp(buf + 9, "276", 3) == 0) refuse("Bullet 2.76 file (its broken DNA is not supported)");
    return buf[6] == 'd';
  }

  // Blocks up to the DNA, as btBulletFile::parseData walks them, and the DNA.
  void readBlocks() {
    const char* buf = buf_;
    int64_t at = 12;
    while (dna_at_ < 0) {
      if (size_ - at < kHead)
        refuse("truncated or corrupt .bullet file (incomplete block header at byte " + std::to_string(at) + ")");
      Block b;
      b.at = at;
      b.code = std::string(buf + at, 4);
      b.len = rd32(buf + at + 4);
      b.old = rd64(buf + at + 8);
      b.dna = rd32(buf + at + 16);
      b.nr = rd32(buf + at + 20);
      if (b.len < 0 || int64_t(b.len) > size_ - at - kHead)
        refuse("truncated or corrupt .bullet file (block '" + code4(buf + at) + "' at byte " + std::to_string(at) +
               " runs past the end of the file)");
      if (b.len % 4)
        fail("block '" + code4(buf + at) + "' at byte " + std::to_string(at) + " has length " + std::to_string(b.len) +
             ", not a multiple of 4");
      if (b.code == "SDNA") fail("SDNA block before the DNA block");
      if (b.code == "DNA1")
        dna_at_ = at;
      else
        blocks_.push_back(b);
      at += kHead + b.len;
    }
    dna_len_ = rd32(buf + dna_at_ + 4);
    if (dna_len_ < 8 || std::memcmp(buf + dna_at_ + kHead, "SDNANAME", 8) != 0) fail("bad DNA block");
    dna_.parse(buf + dna_at_ + kHead, buf + dna_at_ + kHead + dna_len_, fail, "DNA");
    keep_.assign(blocks_.size(), -1);
    struct_checked_.assign(dna_.structs.size(), 0);
    on_stack_.assign(blocks_.size(), 0);
    shape_done_.assign(blocks_.size(), 0);
    height_.assign(blocks_.size(), 0);
    expanded_.assign(blocks_.size(), 1);
  }

  // Blocks by old pointer (Bullet resolves a pointer only to the start of a block), each block's struct index and
  // element count.
  void indexBlocks() {
    for (size_t i = 0; i < blocks_.size(); ++i) {
      const Block& b = blocks_[i];
      if (b.old == 0) fail(where(i) + " has a null address");
      if (!by_old_.emplace(b.old, i).second)
        fail("two blocks with the address " + std::to_string(b.old) + " (at bytes " +
             std::to_string(blocks_[by_old_[b.old]].at) + " and " + std::to_string(b.at) + ")");
      if (b.dna >= int32_t(dna_.structs.size()))
        fail(where(i) + " has struct index " + std::to_string(b.dna) + " out of range");
      if (b.dna >= 0) {
        if (b.nr < 1) fail(where(i) + " has " + std::to_string(b.nr) + " elements");
        if (int64_t(b.nr) * dna_.structLen(b.dna) > int64_t(b.len))
          fail(where(i) + " is shorter than its " + std::to_string(b.nr) + " " + dna_.structName(b.dna) + " elements");
      }
    }
  }

  // The rigid bodies and world records, and everything they reach; returns the number of rigid bodies.
  int64_t checkBodiesAndWorlds(bool dbl) {
    const std::string body_struct = dbl ? "btRigidBodyDoubleData" : "btRigidBodyFloatData";
    const std::string world_struct = dbl ? "btDynamicsWorldDoubleData" : "btDynamicsWorldFloatData";
    int64_t bodies = 0;
    int64_t body_shapes = 0;  // shapes the engine's import makes, over all bodies
    int body_dna = -1;
    int64_t name_off = 0, shape_off = 0;
    for (size_t i = 0; i < blocks_.size(); ++i) {
      const Block& b = blocks_[i];
      if (b.code == "RBDY") {
        checkRecord(i, body_struct, dbl, "rigid bodies");
        mark(i, kBody);
        checkStruct(i);
        if (b.dna != body_dna) {  // the two fields' offsets, once per struct (there are many bodies)
          body_dna = b.dna;
          name_off = field(i, 0, {"m_collisionObjectData", "*m_name"}, nullptr) - data(i);
          shape_off = field(i, 0, {"m_collisionObjectData", "*m_collisionShape"}, nullptr) - data(i);
        }
        name(i, data(i) + name_off);
        // (without a shape Bullet's importer would skip the body, with a message on stdout)
        const uint64_t s = rd64(data(i) + shape_off);
        const int64_t si = s ? pointee(s) : -1;
        if (si < 0) fail(where(i) + ": the rigid body has no shape (its shape pointer leads to no block)");
        shape(size_t(si), 0);
        body_shapes = std::min(body_shapes + expanded_[size_t(si)], kMaxExpanded + 1);
        ++bodies;
      } else if (b.code == "DWLD") {
        checkRecord(i, world_struct, dbl, "world records");
        mark(i, kWorld);
        checkStruct(i);
      }
    }
    if (bodies == 0) refuse("the .bullet file holds no rigid bodies");
    int64_t converted = 0;  // shapes Bullet's importer makes: every kept shape block, expanded
    for (size_t i = 0; i < blocks_.size(); ++i)
      if (keep_[i] == kShape) converted = std::min(converted + expanded_[i], kMaxExpanded + 1);
    if (converted > kMaxExpanded || body_shapes > kMaxExpanded)
      throw InputError(origin_ + ": the shapes expand to more than " + std::to_string(kMaxExpanded) +
                       " primitives (compounds sharing children multiply them; the limit)");
    return bodies;
  }

  // The copy: header, the kept blocks in file order, the DNA block; then Bullet's DNA scan must find that DNA.
  std::string keptCopy() const {
    std::string out(buf_, 12);
    out.reserve(size_t(size_));
    for (size_t i = 0; i < blocks_.size(); ++i)
      if (keep_[i] >= 0) out.append(buf_ + blocks_[i].at, size_t(kHead + blocks_[i].len));
    const int64_t dna_data = int64_t(out.size()) + kHead;
    out.append(buf_ + dna_at_, size_t(kHead + dna_len_));
    if (bulletDnaScan(out.data(), int64_t(out.size())) != dna_data)
      fail("Bullet's scan for the DNA would not find the DNA block (the bytes DNA1 or SDNANAME appear in the data)");
    return out;
  }

 private:
  // The kept blocks and the role each plays; a block reached in two roles is refused.
  enum Role { kBody, kWorld, kShape, kArray, kName };

  [[noreturn]] void refuse(const std::string& what) const { throw InputError(origin_ + ": " + what); }
  std::string where(size_t i) const {
    return "block '" + code4(buf_ + blocks_[i].at) + "' at byte " + std::to_string(blocks_[i].at);
  }
  const char* data(size_t i) const { return buf_ + blocks_[i].at + kHead; }
  int64_t pointee(uint64_t p) const {
    auto it = by_old_.find(p);
    return it == by_old_.end() ? -1 : int64_t(it->second);
  }

  void mark(size_t i, Role r) {
    static const char* const kRoleCode[] = {"RBDY", "DWLD", "SHAP", "ARAY", "ARAY"};
    if (keep_[i] >= 0 && keep_[i] != r) fail(where(i) + " is used in two roles");
    if (std::memcmp(blocks_[i].code.data(), kRoleCode[r], 4) != 0)
      fail(where(i) + " should be a '" + kRoleCode[r] + "' block");
    keep_[i] = r;
  }

  // A rigid-body or world block: one element of the struct of the header's precision.
  void checkRecord(size_t i, const std::string& expected, bool dbl, const char* what) const {
    const Block& b = blocks_[i];
    if (b.dna < 0 || dna_.structName(b.dna) != expected)
      fail(where(i) + " holds " + (b.dna < 0 ? std::string("no struct") : dna_.structName(b.dna)) +
           ", but the header says " + (dbl ? "double" : "float") + " precision (" + expected + ")");
    if (b.nr != 1) fail(where(i) + " holds " + std::to_string(b.nr) + " " + what);
  }

  // A kept struct: one Bullet knows (it converts the block into its own struct of that name, which the importer
  // reads), and where Bullet copies it unconverted instead (equal to its own struct of the same index), that same
  // struct at the same offsets; no pointer-to-pointer members.
  void checkStruct(size_t i) {
    const int s = blocks_[i].dna;
    if (struct_checked_[size_t(s)]) return;
    struct_checked_[size_t(s)] = 1;
    if (mem_.structByName(dna_.structName(s)) < 0)
      fail(where(i) + ": struct " + dna_.structName(s) + " is unknown to Bullet");
    if (copiedUnconverted(dna_, mem_, s) && (mem_.structName(s) != dna_.structName(s) || !sameLayout(dna_, s, mem_, s)))
      fail(where(i) + ": its struct " + dna_.structName(s) + " differs from Bullet's");
    std::vector<int> todo{s};
    for (size_t k = 0; k < todo.size() && k < 256; ++k)
      for (const Dna::Member& m : dna_.structs[size_t(todo[k])].members) {
        if (m.ptrptr)
          fail(where(i) + ": pointer-to-pointer member " + dna_.names[size_t(m.name)] + " in " + dna_.structName(s));
        const int sub = dna_.memberStruct(m);
        if (sub >= 0) todo.push_back(sub);
      }
  }

  // A field of block i's element `elem` at the member path (a.b.c), of the given primitive type or a pointer.
  const char* field(size_t i, int64_t elem, const std::vector<const char*>& path, const char* type) {
    int s = blocks_[i].dna;
    std::string key;
    for (const char* p : path) key += std::string(p) + "/";
    key += type ? type : "*";
    const auto cached = field_offset_.find({s, key});
    if (cached != field_offset_.end()) return data(i) + elem * dna_.structLen(s) + cached->second;
    const int s0 = s;
    int64_t off = 0;
    for (size_t k = 0; k < path.size(); ++k) {
      const Dna::Member* m = dna_.member(s, path[k]);
      if (!m) fail(where(i) + ": " + dna_.structName(s) + " has no member " + path[k]);
      // Bullet converts a block into its own struct of the same name member by member, matching names and, for
      // struct members, type names (else the member stays zero): the value read here must be the one it keeps.
      const int ms = mem_.structByName(dna_.structName(s));
      const Dna::Member* mm = ms >= 0 ? mem_.member(ms, path[k]) : nullptr;
      if (!mm || mm->pointer != m->pointer ||
          (!m->pointer && mem_.types[size_t(mm->type)] != dna_.types[size_t(m->type)]))
        fail(where(i) + ": member " + path[k] + " of " + dna_.structName(s) + " differs from Bullet's");
      off += m->offset;
      if (k + 1 < path.size()) {
        s = dna_.memberStruct(*m);
        if (s < 0) fail(where(i) + ": " + path[k] + " is not a struct");
      } else if (type ? (m->pointer || dna_.types[size_t(m->type)] != type) : !m->pointer) {
        fail(where(i) + ": member " + path[k] + " of " + dna_.structName(s) + " has an unexpected type");
      }
    }
    field_offset_[{s0, key}] = off;
    return data(i) + elem * dna_.structLen(s0) + off;
  }

  // A name pointer (char*): null, or a block of raw bytes (no struct) with a NUL inside it.
  void name(size_t i, const char* p) {
    const uint64_t v = rd64(p);
    if (!v) return;
    const int64_t n = pointee(v);
    if (n < 0) fail(where(i) + ": its name points to no block");
    if (blocks_[size_t(n)].dna >= 0 || !std::memchr(data(size_t(n)), 0, size_t(blocks_[size_t(n)].len)))
      fail(where(size_t(n)) + " is not a NUL-terminated name");
    mark(size_t(n), kName);
  }

  // An array block of at least `count` elements of struct `type`.
  void array(size_t i, const char* p, int64_t count, const char* type, bool may_be_null) {
    const uint64_t v = rd64(p);
    if (!v) {
      if (!may_be_null && count > 0) fail(where(i) + ": null pointer to " + std::to_string(count) + " " + type);
      return;
    }
    const int64_t n = pointee(v);
    if (n < 0) fail(where(i) + ": pointer to " + type + " points to no block");
    const Block& b = blocks_[size_t(n)];
    if (b.dna < 0 || dna_.structName(b.dna) != type) fail(where(size_t(n)) + " should hold " + type);
    if (int64_t(b.nr) < count)
      fail(where(size_t(n)) + " holds " + std::to_string(b.nr) + " " + type + ", fewer than " + std::to_string(count));
    mark(size_t(n), kArray);
    checkStruct(size_t(n));
  }

  // Shapes: the importer casts the data by m_shapeType (btWorldImporter::convertCollisionShape).
  struct ShapeKind {
    int type;
    const char* name;
    const char* data;
  };
  static const ShapeKind* shapeKind(int type) {
    static const ShapeKind kShapes[] = {
        {0, "box", "btConvexInternalShapeData"},    {4, "convex hull", "btConvexHullShapeData"},
        {8, "sphere", "btConvexInternalShapeData"}, {9, "multi-sphere", "btMultiSphereShapeData"},
        {10, "capsule", "btCapsuleShapeData"},      {11, "cone", "btConeShapeData"},
        {13, "cylinder", "btCylinderShapeData"},    {28, "static plane", "btStaticPlaneShapeData"},
        {31, "compound", "btCompoundShapeData"}};
    for (const ShapeKind& k : kShapes)
      if (k.type == type) return &k;
    return nullptr;
  }

  [[noreturn]] void tooDeepError() const {
    throw InputError(origin_ + ": compound shapes nested deeper than " + std::to_string(max_depth_) +
                     " levels (the limit)");
  }

  // Per shape block: checked yet, on the current path (a cycle), how many compounds deep it nests (itself
  // included) and how many shapes it expands to. A shape checked before is not walked again, but its nesting
  // counts from where it is used; Bullet's importer and ours expand shared children every time they are used,
  // so the expansion (2^24 at most over the file) bounds their work.
  void shape(size_t i, int depth) {
    if (on_stack_[i]) fail(where(i) + ": a compound shape contains itself");
    if (shape_done_[i]) {
      if (depth + height_[i] > max_depth_) tooDeepError();
      return;
    }
    mark(i, kShape);
    const Block& b = blocks_[i];
    if (b.dna < 0 || !dna_.derivesFrom(b.dna, "btCollisionShapeData")) fail(where(i) + " is not a collision shape");
    checkStruct(i);
    // m_name and m_shapeType of the btCollisionShapeData at the start of the struct, by the path of first members
    std::vector<const char*> base;
    for (int st = b.dna; dna_.structName(st) != "btCollisionShapeData";) {
      const Dna::Member& first = dna_.structs[size_t(st)].members[0];
      base.push_back(dna_.names[size_t(first.name)].c_str());
      st = dna_.memberStruct(first);
    }
    std::vector<const char*> name_path = base, type_path = base;
    name_path.push_back("*m_name");
    type_path.push_back("m_shapeType");
    name(i, field(i, 0, name_path, nullptr));
    const int type = rd32(field(i, 0, type_path, "int"));
    const ShapeKind* kind = shapeKind(type);
    if (!kind)
      throw InputError(origin_ + ": shape type " + std::to_string(type) + " at byte " + std::to_string(b.at) +
                       " is not supported (dvisim imports box, sphere, capsule, cylinder, cone, convex hull, "
                       "multi-sphere, compound and static plane shapes)");
    if (!dna_.derivesFrom(b.dna, kind->data) ||
        !mem_.derivesFrom(mem_.structByName(dna_.structName(b.dna)), kind->data))
      fail(where(i) + ": a " + kind->name + " shape stored as " + dna_.structName(b.dna));
    if (type == 10 || type == 11 || type == 13) {  // the importer makes no shape for another axis
      const int32_t axis = rd32(field(i, 0, {type == 11 ? "m_upIndex" : "m_upAxis"}, "int"));
      if (axis < 0 || axis > 2) fail(where(i) + ": a " + kind->name + " along axis " + std::to_string(axis));
    } else if (type == 31) {
      compound(i, depth);
    } else if (type == 9) {
      const int32_t n = rd32(field(i, 0, {"m_localPositionArraySize"}, "int"));
      if (n < 1) fail(where(i) + ": a multi-sphere of " + std::to_string(n) + " spheres");
      expanded_[i] = n;
      array(i, field(i, 0, {"*m_localPositionArrayPtr"}, nullptr), n, "btPositionAndRadius", false);
    } else if (type == 4) {
      const int32_t n = rd32(field(i, 0, {"m_numUnscaledPoints"}, "int"));
      if (n < 0) fail(where(i) + ": a convex hull of " + std::to_string(n) + " points");
      array(i, field(i, 0, {"*m_unscaledPointsFloatPtr"}, nullptr), n, "btVector3FloatData", true);
      array(i, field(i, 0, {"*m_unscaledPointsDoublePtr"}, nullptr), n, "btVector3DoubleData", true);
    }
    shape_done_[i] = 1;
  }

  // A compound shape block's children, each walked as a shape one level deeper.
  void compound(size_t i, int depth) {
    if (depth >= max_depth_) tooDeepError();
    const int32_t n = rd32(field(i, 0, {"m_numChildShapes"}, "int"));
    if (n < 0) fail(where(i) + ": a compound of " + std::to_string(n) + " children");
    const char* p = field(i, 0, {"*m_childShapePtr"}, nullptr);
    array(i, p, n, "btCompoundShapeChildData", false);
    height_[i] = 1;
    expanded_[i] = 0;
    if (n == 0) return;
    const size_t c = size_t(pointee(rd64(p)));
    on_stack_[i] = 1;
    for (int32_t k = 0; k < n; ++k) {
      const uint64_t child = rd64(field(c, k, {"*m_childShape"}, nullptr));
      const int64_t ci = child ? pointee(child) : -1;
      if (ci < 0) fail(where(c) + ": compound child " + std::to_string(k) + " has no shape");
      shape(size_t(ci), depth + 1);
      height_[i] = std::max(height_[i], 1 + height_[size_t(ci)]);
      expanded_[i] = std::min(expanded_[i] + expanded_[size_t(ci)], kMaxExpanded + 1);
    }
    on_stack_[i] = 0;
  }

  const Fail fail;
  const std::string origin_;
  const int max_depth_;
  const char* const buf_;
  const int64_t size_;
  std::vector<Block> blocks_;
  int64_t dna_at_ = -1;
  int32_t dna_len_ = 0;
  Dna dna_;
  const Dna& mem_ = memoryDna();
  std::unordered_map<uint64_t, size_t> by_old_;
  std::vector<int> keep_;  // the role of each kept block, -1 for the others
  std::vector<char> struct_checked_;
  std::map<std::pair<int, std::string>, int64_t> field_offset_;  // (struct, path) -> offset, looked up once
  std::vector<char> on_stack_, shape_done_;
  std::vector<int> height_;
  std::vector<int64_t> expanded_;
};

// The checked copy of `file` (see above). Throws InputError naming `origin` and the problem.
// `rigid_bodies` receives the number of rigid-body blocks kept.
inline std::string sanitizeBulletFile(const std::string& file, const std::string& origin, int max_compound_depth,
                                      int64_t* rigid_bodies = nullptr) {
  FileChecker check(file, origin, max_compound_depth);
  const bool dbl = check.checkHeader();
  check.readBlocks();
  check.indexBlocks();
  const int64_t bodies = check.checkBodiesAndWorlds(dbl);
  if (rigid_bodies) *rigid_bodies = bodies;
  return check.keptCopy();
}

}  // namespace bulletfile
}  // namespace dvi
