// Several processes solving one CCP together, each with its own share of the contacts (a domain decomposition:
// chrono_like/mpi/distributed_system.h). What the solver, the contact problem and the System ask of them; the
// System holds none unless a distributed driver hands one down (System::setProcessGroup).
//
// The product N x = D^T M^-1 D x (docs/MODEL.md §4) is a gather over each body's contacts (pass (a)) and a pass over
// the contacts (pass (b)). A body whose contacts lie in several processes gets each process's share of M^-1 D x in
// pass (a); exchangeDeltas sums the shares onto the body's owner and hands the sum back to every process that holds
// a copy, so pass (b) reads the same velocity change everywhere. Every scalar reduction of the solvers (dot
// products, norms, step tests) is summed over the processes (sum). The iterates then equal one process's up to the
// order of summation.
#pragma once

#include <cstdint>

#include "chrono_like/solver/jacobian.h"

namespace dvi {

class ProcessGroup {
 public:
  virtual ~ProcessGroup() = default;
  // v[0 .. n) summed over the processes, in place; every process gets the same sums.
  virtual void sum(double* v, int n) const = 0;
  // The largest v over the processes.
  virtual double max(double v) const = 0;
  // Whether any process's `local` is true.
  bool any(bool local) const { return max(local ? 1.0 : 0.0) > 0; }
  // Body i (local index) is also held by another process: pass (a) computes its share even where no local contact
  // touches it (a zero share), so that exchangeDeltas sums fresh values.
  virtual bool shared(int32_t body) const = 0;
  // delta[i] of every shared body: this process's share in, the sum over the processes out.
  virtual void exchangeDeltas(BodyDelta* delta) const = 0;
  // Whether this process solves the contact between local bodies a and b (exactly one process does).
  virtual bool ownsContact(int32_t body_a, int32_t body_b) const = 0;
};

}  // namespace dvi
