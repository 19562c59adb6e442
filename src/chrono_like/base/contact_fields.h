// The fields of a contact list, named once for the host's ContactArrays (data.h) and the device's DeviceContacts
// (gpu/gpu_state.cuh): f(array) for each of them, so that both copies resize (and clear) the same fields.
#pragma once

namespace dvi {

template <class Contacts, class F>
void forEachContactField(Contacts& c, F&& f) {
  f(c.shape_a);
  f(c.shape_b);
  f(c.body_a);
  f(c.body_b);
  f(c.normal);
  f(c.pa);
  f(c.pb);
  f(c.dist);
  f(c.mu);
  f(c.size);
  f(c.key);
}

}  // namespace dvi
