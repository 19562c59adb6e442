// The Schur product's velocity-change exchange GPU to GPU (GpuTuning::peer_exchange; PeerExchange in gpu_state.cuh).
// Over several processes of one host every process writes its listed bodies' shares into a buffer of its own device
// memory that the others have opened through CUDA IPC (cudaIpcGetMemHandle / cudaIpcOpenMemHandle: the CUDA C++
// Programming Guide, "Interprocess Communication"). Per product: the host waits for its own shares (an event), meets
// its neighbours (ProcessGroup::awaitNeighbours: an empty message each way, so every neighbour's shares are in place),
// and queues a kernel that sums each listed body's terms in rank order, reading the neighbours' shares from their
// memory over NVLink or PCIe, on a second stream while the gather does the other bodies. The host path (gpu_decomposition.cu)
// copies the shares to pinned memory and sends them with MPI, ~1 ms a product for 46,000 shared bodies on an H100
// host; here only the two empty messages cross the host.
//
// Slots: a product writes the slot of its parity and the next one the other. A neighbour q reads this process's
// slot of product k only after both met at k; this process writes that slot again at k + 2, after meeting q at
// k + 1, which q does only once its event of k + 1 completed, that is after its sum kernel of k (queued before it on
// q's stream) has read the slot.
#include <cuda_runtime.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "gpu/gpu_state.cuh"
#include "gpu/solver/gpu_reduce.cuh"

namespace dvi::gpu {

namespace {

// Each listed body's sum of its terms in rank order (the order of MpiGroup::exchangeCompact: the same sum on every
// process holding the body, and the host path's sum bit for bit), written over the gather's value.
struct PeerSumF {
  const int32_t *start, *rank, *index;
  BodyDelta* const* slots;  // this product's slot of every process
  const int32_t* ids;
  BodyDelta* delta;
  __device__ void operator()(int64_t j) const {
    BodyDelta sum{{0, 0, 0}, {0, 0, 0}};
    for (int32_t t = start[j]; t < start[j + 1]; ++t) {
      // Another device's memory, written by a finished kernel there: read through L2, never a stale L1 line.
      const real* s = reinterpret_cast<const real*>(slots[rank[t]] + index[t]);
      sum.v = sum.v + Vec3{__ldcg(s), __ldcg(s + 1), __ldcg(s + 2)};
      sum.w = sum.w + Vec3{__ldcg(s + 3), __ldcg(s + 4), __ldcg(s + 5)};
    }
    delta[ids[j]] = sum;
  }
};
static_assert(sizeof(BodyDelta) == 6 * sizeof(real), "PeerSumF reads a share as 6 reals");

struct MarkListedF {
  const int32_t* ids;
  uint8_t* listed;
  __device__ void operator()(int64_t j) const { listed[ids[j]] = 1; }
};

// What a process tells the others about its buffer.
struct Published {
  int32_t ok = 0;
  int32_t device = -1;
  uint64_t cap = 0;
  cudaIpcMemHandle_t handle{};
};

void closeOpened(PeerExchange& P) {
  for (void*& p : P.opened)
    if (p) {
      cudaIpcCloseMemHandle(p);  // a failure leaves nothing to undo
      p = nullptr;
    }
}

void freeOwn(PeerExchange& P) {
  if (P.own) cudaFree(P.own);
  P.own = nullptr;
  P.cap = 0;
}

// This process's buffer for `need` shares a slot (grown where `grow`), published to all; every other process's
// opened. Collective. Returns false where any process failed (nothing is left open then).
bool shareBuffers(DeviceState& d, size_t need, bool grow) {
  PeerExchange& P = d.peer;
  ProcessGroup& g = *d.group;
  const int np = g.size(), me = g.rank();
  closeOpened(P);
  g.any(false);  // every process has closed its mappings before any buffer is freed
  bool ok = true;
  if (grow) {
    freeOwn(P);
    const size_t cap = std::max<size_t>(need + need / 4, 4096);
    if (cudaMalloc(&P.own, 2 * cap * sizeof(BodyDelta)) == cudaSuccess) {
      P.cap = cap;
    } else {
      (void)cudaGetLastError();
      P.own = nullptr;
      ok = false;
    }
  }
  Published mine;
  DVI_CUDA(cudaGetDevice(&mine.device));
  mine.cap = P.cap;
  mine.ok = ok && cudaIpcGetMemHandle(&mine.handle, P.own) == cudaSuccess ? 1 : 0;
  if (!mine.ok) (void)cudaGetLastError();
  std::vector<uint8_t> bytes(sizeof mine);
  std::memcpy(bytes.data(), &mine, sizeof mine);
  const std::vector<std::vector<uint8_t>> all = g.allgatherBytes(bytes);
  P.opened.assign(size_t(np), nullptr);
  std::vector<BodyDelta*> slots(2 * size_t(np), nullptr);
  for (int q = 0; q < np; ++q) {
    Published pub;
    if (all[size_t(q)].size() != sizeof pub) throw std::logic_error("peer exchange: a process published no buffer");
    std::memcpy(&pub, all[size_t(q)].data(), sizeof pub);
    ok = ok && pub.ok != 0;
    BodyDelta* base = P.own;
    if (q != me && ok) {
      int reach = 1;
      if (pub.device != mine.device) DVI_CUDA(cudaDeviceCanAccessPeer(&reach, mine.device, pub.device));
      void* p = nullptr;
      if (reach && cudaIpcOpenMemHandle(&p, pub.handle, cudaIpcMemLazyEnablePeerAccess) == cudaSuccess) {
        P.opened[size_t(q)] = p;
      } else {
        (void)cudaGetLastError();
        ok = false;
      }
      base = static_cast<BodyDelta*>(p);
    }
    slots[size_t(q)] = base;
    slots[size_t(np + q)] = base ? base + pub.cap : nullptr;
  }
  if (g.any(!ok)) {
    closeOpened(P);
    g.any(false);
    freeOwn(P);
    return false;
  }
  P.slots.upload(slots, d.stream);
  return true;
}

}  // namespace

void preparePeerExchange(DeviceState& d, bool allowed) {
  PeerExchange& P = d.peer;
  ProcessGroup& g = *d.group;
  if (P.state < 0) return;
  if (P.state == 0) {  // the same answer on every process
    if (g.any(!(allowed && g.size() > 1 && g.oneHost()))) {
      P.state = -1;
      return;
    }
    DVI_CUDA(cudaEventCreateWithFlags(&P.ev_list, cudaEventDisableTiming));
    DVI_CUDA(cudaEventCreateWithFlags(&P.ev_sums, cudaEventDisableTiming));
  }
  const bool grow = P.own == nullptr || d.ex_count > P.cap;
  if (g.any(grow)) {
    if (!shareBuffers(d, d.ex_count, grow)) {
      P.state = -1;
      return;
    }
    P.parity = 0;
  }
  P.state = 1;
  std::vector<int32_t> start, rank, index;
  g.exchangeTerms(start, rank, index);
  P.term_start.upload(start, d.stream);
  P.term_rank.upload(rank, d.stream);
  P.term_index.upload(index, d.stream);
  const int64_t nb = int64_t(d.bodies.count);
  P.listed.resize(size_t(std::max<int64_t>(nb, 1)));
  P.listed.fillZero(d.stream);
  launchMap(d, int64_t(d.ex_count), MarkListedF{d.ex_ids.data(), P.listed.data()}, "launch of MarkListedF");
}

BodyDelta* peerSharesSlot(DeviceState& d) { return d.peer.own + size_t(d.peer.parity) * d.peer.cap; }

void receivePeerSums(DeviceState& d, BodyDelta* delta) {
  PeerExchange& P = d.peer;
  const int64_t n = int64_t(d.ex_count);
  DVI_CUDA(cudaEventSynchronize(P.ev_list));
  d.group->awaitNeighbours(int64_t(sizeof(BodyDelta)) * n);
  if (n > 0) {  // on copy_stream, beside the gather (which skips the listed bodies); pass (b) waits for both
    DVI_CUDA(cudaStreamWaitEvent(d.copy_stream, P.ev_list, 0));
    mapKernel<<<blocksFor(n), kBlock, 0, d.copy_stream>>>(
        n, PeerSumF{P.term_start.data(), P.term_rank.data(), P.term_index.data(),
                    P.slots.data() + size_t(P.parity) * size_t(d.group->size()), d.ex_ids.data(), delta});
    DVI_CUDA_LAUNCH("PeerSumF");
    DVI_CUDA(cudaEventRecord(P.ev_sums, d.copy_stream));
    DVI_CUDA(cudaStreamWaitEvent(d.stream, P.ev_sums, 0));
  }
  P.parity ^= 1;
}

void closePeerExchange(DeviceState& d) {
  PeerExchange& P = d.peer;
  closeOpened(P);
  freeOwn(P);
  if (P.ev_list) cudaEventDestroy(P.ev_list);
  if (P.ev_sums) cudaEventDestroy(P.ev_sums);
  P.ev_list = P.ev_sums = nullptr;
  P.state = 0;
}

}  // namespace dvi::gpu
