// Conversions between Bullet's math types and ours (one copy for every Bullet bridge file).
#pragma once

#include <LinearMath/btQuaternion.h>
#include <LinearMath/btTransform.h>
#include <LinearMath/btVector3.h>

#include "chrono_like/base/math.h"

namespace dvi {

inline Vec3 fromBt(const btVector3& v) { return Vec3{real(v.x()), real(v.y()), real(v.z())}; }
inline btVector3 toBt(Vec3 v) { return btVector3(btScalar(v.x), btScalar(v.y), btScalar(v.z)); }
inline Quat fromBt(const btQuaternion& q) { return Quat{real(q.w()), real(q.x()), real(q.y()), real(q.z())}; }
inline btQuaternion toBt(Quat q) { return btQuaternion(btScalar(q.x), btScalar(q.y), btScalar(q.z), btScalar(q.w)); }
// Bullet's quaternions are single precision in a float build: renormalised on the way in.
inline Pose fromBt(const btTransform& t) { return Pose{fromBt(t.getOrigin()), normalized(fromBt(t.getRotation()))}; }
inline btTransform toBt(const Pose& p) { return btTransform(toBt(p.q), toBt(p.p)); }

}  // namespace dvi
