// A scene run's checkpoint piece: one process's bodies and the impulses of the contacts it solved, under global (scene)
// ids and keys, so that any number of processes can resume from the pieces together. An MPI run writes one a process
// (DistributedSystem::checkpointPiece), a single process one for all its bodies (apps/dvisim/run_checkpoint.h); no MPI
// here, so it is part of the core library. The file, little-endian as the machine writes it (format DVIMPI02):
//   "DVIMPI02" | u64 bodies | bodies x (i32 id, 13 reals: pos, rot, vel, omega) | u64 contacts |
//   contacts x (u64 key, i32 body_a, i32 body_b, 3 reals: impulses, 3 reals: normal) | u64 FNV-1a 64 (checksum.h)
//   of every byte before it.
// The normal is what the next step's narrow phase reads as last step's (CollisionSettings::mpr_coherence), so a run
// resumed from the piece steps as the run that wrote it. The earlier format DVIMPI01 (no normals) is still read: its
// contacts get a zero normal, which the narrow phase never takes for last step's, and it encodes back as DVIMPI01.
// decodePiece checks the checksum before it reads a field, then every field (ids in range and ascending, finite
// numbers, unit rotations): InputError naming the problem.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "chrono_like/system.h"

namespace dvi {

// A body's state as the decomposition moves it (DistributedSystem) and a checkpoint stores it.
struct MotionState {
  Vec3 pos;
  Quat rot;
  Vec3 vel, omega;
};

constexpr char kMpiCheckpointMagic[9] = "DVIMPI02";
constexpr char kMpiCheckpointMagicV1[9] = "DVIMPI01";  // without normals (read, and written back as read)

struct CheckpointPiece {
  std::vector<int32_t> ids;  // ascending
  std::vector<MotionState> states;
  std::vector<ContactImpulse> impulses;  // global contact keys and body ids
  int format = 2;                        // 2: DVIMPI02; 1: a DVIMPI01 piece as read
};

std::string encodePiece(const CheckpointPiece& p);
// `what` names the file in messages; bodies: the scene's body count (ids must be below it).
CheckpointPiece decodePiece(const std::string& bytes, const std::string& what, size_t bodies);

}  // namespace dvi
