// The launches of the Schur product (gpu_schur.cuh): pass (a), the gather, one thread per body and the heavy
// bodies by chunks of blocks; pass (b), one thread per contact (or normal row) and per constraint row.
#include <cuda_runtime.h>

#include <cstdint>
#include <type_traits>

#include "gpu/gpu_state.cuh"
#include "gpu/solver/gpu_reduce.cuh"
#include "gpu/solver/gpu_schur.cuh"

namespace dvi::gpu {

namespace {

// Heavy bodies are gathered by kHeavyChunks blocks each (grid kHeavyChunks x n_heavy), block (c, h) summing
// chunk c of heavy body h. One block per body made every Schur product wait for the drum: 31 us of a 65 us
// APGD trial in the CES industrial feed (15,000 entries, H200 ncu).
template <class JT>
__global__ void __launch_bounds__(kBlock)
    HeavyGatherKernel(const int32_t* heavy, GatherT<JT> g, real* partial, uint32_t* ticket) {
  const real* x = g.input();
  if (!x) return;  // the same for every block of the launch
  heavyGatherChunk(heavy, g, x, partial, ticket, int32_t(blockIdx.y), int32_t(blockIdx.x));
}

// The velocity change of each body of the exchange list (a domain decomposition), into the compact exchange buffer:
// all its entries in order, in one thread even for a heavy body.
template <class JT>
struct ListGatherF {
  GatherT<JT> g;
  const int32_t* ids;
  BodyDelta* out;
  __device__ void operator()(int64_t j) const {
    const real* xx = g.input();
    const int32_t i = ids[j];
    if (!xx) {  // a done device loop's slot: nothing is read
      out[j] = BodyDelta{};
      return;
    }
    Vec3 F{0, 0, 0}, T{0, 0, 0};
    for (int32_t e = g.off[i]; e < g.off[i + 1]; ++e) g.entry(e, xx, F, T);
    out[j] = g.bodyDelta(i, F, T);
  }
};

}  // namespace

template <class JT>
void gather(DeviceState& d, const real* x, const char* what, const real* const* x_slot, const JT* jac) {
  SolverScratch& S = d.solver;
  if constexpr (std::is_same_v<JT, ContactJacobian>) {
    if (!jac) jac = S.jac.data();
  }
  GatherT<JT> g = gatherOf(d, jac, x, x_slot);
  // Over several processes the shared bodies' shares go first and travel to the other processes while every body's
  // gather runs; their sums then replace the gather's values.
  // GPU to GPU (PeerExchange) the shares go to a slot the neighbours read, else through pinned host memory.
  const bool exchange = d.group != nullptr, peer = exchange && d.peer.state == 1;
  if (exchange) {
    launchMap(d, int64_t(d.ex_count), ListGatherF<JT>{g, d.ex_ids.data(), peer ? peerSharesSlot(d) : d.ex_buf.data()},
              "launch of ListGatherF (shared bodies' shares)");
    if (peer) {
      DVI_CUDA(cudaEventRecord(d.peer.ev_list, d.stream));
      g.skip = d.peer.listed.data();  // their sums come from receivePeerSums, beside the gather
    } else {
      sendSharesAsync(d);
    }
  }
  launchMap(d, int64_t(d.bodies.count), g, what);
  if (S.n_heavy > 0) {
    HeavyGatherKernel<JT><<<dim3(kHeavyChunks, unsigned(S.n_heavy)), kBlock, 0, d.stream>>>(
        S.heavy.data(), g, S.heavy_partial.data(), S.heavy_ticket.data());
    cudaCheck(cudaGetLastError(), "launch of HeavyGatherKernel", __FILE__, __LINE__);
  }
  if (peer)
    receivePeerSums(d, d.bodies.delta.data());
  else if (exchange)
    receiveSums(d, d.bodies.delta.data());
}

template <class V>
void schur(DeviceState& d, const real* x, V* y, const real* const* x_slot, V* const* y_slot, const real* add) {
  using JT = std::conditional_t<std::is_same_v<V, real>, ContactJacobian, ContactJacobianF>;
  SolverScratch& S = d.solver;
  const JT* jac = contactJacobians<JT>(S);
  const int64_t nc = int64_t(d.contacts.count);
  const SchurOut<V> out{y, y_slot, add};
  gather<JT>(d, x, "launch of GatherF (Schur pass a)", x_slot, jac);
  if (d.normal_only)
    launchMap(d, 3 * d.contact_blocks, NormalContactF<V, JT>{jac, d.bodies.delta.data(), nc, out},
              "launch of NormalContactF (Schur pass b, normal rows)");
  else
    launchMap(d, nc, ContactF<V, JT>{jac, d.bodies.delta.data(), out}, "launch of ContactF (Schur pass b)");
  launchMap(d, int64_t(S.rows.size()), RowSchurF<V>{S.rows.data(), d.bodies.delta.data(), out, 3 * d.contact_blocks},
            "launch of RowSchurF (Schur pass b, rows)");
}

// The instantiations the other files call: the impulses' gather (gpu_solver.cu), the Schur product of the real
// vectors (GpuOps) and of the APGD trials' storage types (gpu_apgd_trials.cu).
template void gather<ContactJacobian>(DeviceState&, const real*, const char*, const real* const*,
                                      const ContactJacobian*);
template void schur<real>(DeviceState&, const real*, real*, const real* const*, real* const*, const real*);
#if !defined(DVISIM_SINGLE_PRECISION)
template void schur<float>(DeviceState&, const real*, float*, const real* const*, float* const*, const real*);
#endif

}  // namespace dvi::gpu
