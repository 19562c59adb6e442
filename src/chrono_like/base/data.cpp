#include "chrono_like/base/data.h"

#include "chrono_like/base/contact_fields.h"

namespace dvi {

void BodyArrays::resize(size_t n) {
  pos.resize(n);
  rot.resize(n, Quat{1, 0, 0, 0});
  vel.resize(n);
  omega.resize(n);
  inv_mass.resize(n);
  inv_inertia.resize(n);
  force.resize(n);
  torque.resize(n);
  gravity.resize(n);
  friction.resize(n);
  restitution.resize(n);
  rolling_friction.resize(n);
  spinning_friction.resize(n);
  flags.resize(n);
  shape_start.resize(n);
  shape_count.resize(n);
  size.resize(n);
}

void ContactArrays::resize(size_t n) {
  forEachContactField(*this, [n](auto& field) { field.resize(n); });
}

void ContactArrays::moveContact(size_t from, size_t to) {
  shape_a[to] = shape_a[from];
  shape_b[to] = shape_b[from];
  body_a[to] = body_a[from];
  body_b[to] = body_b[from];
  normal[to] = normal[from];
  pa[to] = pa[from];
  pb[to] = pb[from];
  dist[to] = dist[from];
  key[to] = key[from];
}

void ContactArrays::clear() { resize(0); }

}  // namespace dvi
