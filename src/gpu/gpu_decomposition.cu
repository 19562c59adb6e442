// The domain decomposition's device side (solver/process_group.h, chrono_like/mpi/distributed_system.h): the owned
// contacts kept by the ownership rule of contactOwner (the very function the CPU System calls), the copies they touch
// named to the group, the velocity-change exchange staged through pinned host memory, and the selections the
// distributed driver reads between steps (the fastest owned body, the owned bodies near a face of the process's box,
// the contacts of bodies that change process). Only the selected elements cross the bus.
#include <cuda_runtime.h>
#include <thrust/iterator/counting_iterator.h>

#include <algorithm>
#include <cstdint>
#include <cub/cub.cuh>
#include <vector>

#include "gpu/cub_call.cuh"
#include "gpu/gpu_state.cuh"
#include "gpu/solver/gpu_reduce.cuh"

namespace dvi::gpu {

namespace {

struct OwnedContactF {
  const int32_t *a, *b, *owner, *key;
  int rank;
  uint8_t* keep;
  __device__ void operator()(int64_t k) const {
    const int32_t x = a[k], y = b[k];
    keep[k] = contactOwner(owner[x], owner[y], key[x], key[y]) == rank ? 1 : 0;
  }
};

template <class T>
struct GatherByF {
  const int32_t* idx;
  const T* in;
  T* out;
  __device__ void operator()(int64_t i) const { out[i] = in[idx[i]]; }
};

template <class T>
struct ScatterByF {
  const int32_t* idx;
  const T* in;
  T* out;
  __device__ void operator()(int64_t i) const { out[idx[i]] = in[i]; }
};

struct PackValueF {
  const int32_t* idx;
  const real* in;
  BodyDelta* out;
  __device__ void operator()(int64_t i) const { out[i] = BodyDelta{{in[idx[i]], 0, 0}, {0, 0, 0}}; }
};

struct UnpackValueF {
  const int32_t* idx;
  const BodyDelta* in;
  real* out;
  __device__ void operator()(int64_t i) const { out[idx[i]] = in[i].v.x; }
};

// Marks the copies of other processes' bodies (owner >= 0, not this process) that contact k touches (a benign race:
// every writer writes 1).
struct TouchF {
  const int32_t *a, *b, *owner;
  int rank;
  uint8_t* mark;
  __device__ void operator()(int64_t k) const {
    const int32_t oa = owner[a[k]], ob = owner[b[k]];
    if (oa >= 0 && oa != rank) mark[a[k]] = 1;
    if (ob >= 0 && ob != rank) mark[b[k]] = 1;
  }
};

// Marks the current copies (owner >= 0, not this process) whose centre lies in [lo, hi] (ProcessGroup::listedRegion).
struct RegionCopyF {
  const Vec3* pos;
  const int32_t* owner;
  int rank;
  Vec3 lo, hi;
  uint8_t* mark;
  __device__ void operator()(int64_t i) const {
    const int32_t o = owner[i];
    if (o >= 0 && o != rank && insideBox(pos[i], lo, hi)) mark[i] = 1;
  }
};

__device__ bool mineOf(const int32_t* owner, const uint8_t* flags, int rank, int64_t i) {
  return owner ? owner[i] == rank : (flags[i] & (kBodyFixed | kBodyKinematic)) == 0;
}

// The largest |v| and |w| of the owned bodies: a fixed grid strides over the bodies, each block's maxima (a warp
// shuffle, then its warps in shared memory) go to out[0..1] with one atomicMax each, on the bits of non-negative
// doubles (ordered as the integers are).
__global__ void motionMaxKernel(int64_t n, const Vec3* vel, const Vec3* omega, const int32_t* owner,
                                const uint8_t* flags, int rank, unsigned long long* out) {
  double v = 0, w = 0;
  for (int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < n; i += int64_t(gridDim.x) * blockDim.x)
    if (mineOf(owner, flags, rank, i)) {
      v = fmax(v, double(length(vel[i])));
      w = fmax(w, double(length(omega[i])));
    }
  for (int o = 16; o > 0; o >>= 1) {
    v = fmax(v, __shfl_down_sync(0xffffffffu, v, o));
    w = fmax(w, __shfl_down_sync(0xffffffffu, w, o));
  }
  __shared__ double sv[kBlock / 32], sw[kBlock / 32];
  const int lane = threadIdx.x & 31, warp = threadIdx.x >> 5;
  if (lane == 0) sv[warp] = v, sw[warp] = w;
  __syncthreads();
  if (threadIdx.x != 0) return;
  for (int k = 1; k < kBlock / 32; ++k) v = fmax(v, sv[k]), w = fmax(w, sw[k]);
  v = fmax(v, sv[0]);
  w = fmax(w, sw[0]);
  atomicMax(out, (unsigned long long)__double_as_longlong(v));
  atomicMax(out + 1, (unsigned long long)__double_as_longlong(w));
}

struct OutsideF {
  const Vec3* pos;
  const int32_t* owner;
  const uint8_t* flags;
  int rank;
  Vec3 lo, hi;
  uint8_t* mark;
  __device__ void operator()(int64_t i) const {
    mark[i] = mineOf(owner, flags, rank, i) && !insideBox(pos[i], lo, hi) ? 1 : 0;
  }
};

struct TouchingF {
  const int32_t *a, *b, *ids;
  int64_t n;
  uint8_t* mark;
  __device__ void operator()(int64_t k) const {
    mark[k] = findSorted(ids, n, a[k]) >= 0 || findSorted(ids, n, b[k]) >= 0 ? 1 : 0;
  }
};

struct ImpulseRecordF {
  const int32_t* sel;
  const uint64_t* key;
  const int32_t *a, *b;
  const real* gamma;
  const Vec3* normal;
  ContactImpulse* out;
  __device__ void operator()(int64_t i) const {
    const int64_t k = sel[i];
    out[i] = ContactImpulse{key[k], a[k], b[k], {gamma[3 * k], gamma[3 * k + 1], gamma[3 * k + 2]}, normal[k]};
  }
};

// The indices i < n with flags[i] != 0, ascending, into d.sel; returns their count (one read-back).
int64_t selectFlagged(DeviceState& d, int64_t n, const uint8_t* flags, const char* what) {
  d.sel.resize(size_t(std::max<int64_t>(n, 1)));
  d.sel_count.resize(1);
  if (n == 0) return 0;
  thrust::counting_iterator<int32_t> first(0);
  cubRun(d, what, [&](void* t, size_t& bytes) {
    return cub::DeviceSelect::Flagged(t, bytes, first, flags, d.sel.data(), d.sel_count.data(), int(n), d.stream);
  });
  return int64_t(d.readValue(d.sel_count.data()));
}

std::vector<int32_t> downloadSelection(DeviceState& d, int64_t n) {
  std::vector<int32_t> out(static_cast<size_t>(n));
  if (n > 0) {
    DVI_CUDA(cudaMemcpyAsync(out.data(), d.sel.data(), sizeof(int32_t) * size_t(n), cudaMemcpyDeviceToHost, d.stream));
    DVI_CUDA(cudaStreamSynchronize(d.stream));
  }
  return out;
}

template <class T>
void keepBy(DeviceState& d, DeviceBuffer<T>& from, DeviceBuffer<T>& scratch, int64_t kept, const char* what) {
  scratch.resize(size_t(kept));
  launchMap(d, kept, GatherByF<T>{d.sel.data(), from.data(), scratch.data()}, what);
  from.swap(scratch);
}

// The pinned staging of the exchange list's values, grown to n.
void reserveExchange(DeviceState& d, size_t n) {
  d.ex_buf.resize(std::max<size_t>(n, 1));
  if (n <= d.ex_host_cap) return;
  if (d.ex_host) DVI_CUDA(cudaFreeHost(d.ex_host));
  d.ex_host = nullptr;
  const size_t cap = n + n / 2;
  DVI_CUDA(cudaMallocHost(&d.ex_host, cap * sizeof(BodyDelta)));
  d.ex_host_cap = cap;
}

}  // namespace

void uploadOwners(DeviceState& d) {
  if (!d.group) return;
  const std::vector<int32_t> changed = d.group->takeOwnerChanges();
  const std::vector<int32_t>& owner = d.group->bodyOwners();
  if (d.group->bodiesVersion() != d.owners_version) {  // new local bodies: both arrays
    d.owner.upload(owner, d.stream);
    d.owner_key.upload(d.group->bodyKeys(), d.stream);
    d.owners_version = d.group->bodiesVersion();
  } else if (!changed.empty()) {  // the changed owners alone
    std::vector<int32_t> values(changed.size());
    for (size_t j = 0; j < changed.size(); ++j) values[j] = owner[size_t(changed[j])];
    d.sel.upload(changed, d.stream);
    d.ex_scatter.upload(values, d.stream);
    launchMap(d, int64_t(changed.size()), ScatterByF<int32_t>{d.sel.data(), d.ex_scatter.data(), d.owner.data()},
              "launch of ScatterByF (owners)");
  } else {
    return;
  }
  DVI_CUDA(cudaStreamSynchronize(d.stream));  // the host vectors may change after we return
}

void keepOwnedContacts(DeviceState& d, bool peer_exchange) {
  uploadOwners(d);
  const int rank = d.group->rank();
  DeviceContacts& c = d.contacts;
  const int64_t nc = int64_t(c.count);
  d.mark.resize(size_t(std::max<int64_t>(nc, 1)));
  launchMap(d, nc,
            OwnedContactF{c.body_a.data(), c.body_b.data(), d.owner.data(), d.owner_key.data(), rank, d.mark.data()},
            "launch of OwnedContactF");
  const int64_t kept = selectFlagged(d, nc, d.mark.data(), "cub::DeviceSelect::Flagged (owned contacts)");
  if (kept < nc) {
    DeviceContacts& o = d.contacts_kept;
    keepBy(d, c.shape_a, o.shape_a, kept, "launch of GatherByF (shape_a)");
    keepBy(d, c.shape_b, o.shape_b, kept, "launch of GatherByF (shape_b)");
    keepBy(d, c.body_a, o.body_a, kept, "launch of GatherByF (body_a)");
    keepBy(d, c.body_b, o.body_b, kept, "launch of GatherByF (body_b)");
    keepBy(d, c.normal, o.normal, kept, "launch of GatherByF (normal)");
    keepBy(d, c.pa, o.pa, kept, "launch of GatherByF (pa)");
    keepBy(d, c.pb, o.pb, kept, "launch of GatherByF (pb)");
    keepBy(d, c.dist, o.dist, kept, "launch of GatherByF (dist)");
    keepBy(d, c.mu, o.mu, kept, "launch of GatherByF (mu)");
    keepBy(d, c.size, o.size, kept, "launch of GatherByF (size)");
    keepBy(d, c.key, o.key, kept, "launch of GatherByF (key)");
    c.count = size_t(kept);
  }
  // The copies the kept contacts touch, to the group (collective), and the step's exchange list back.
  const int64_t nb = int64_t(d.bodies.count);
  d.mark.resize(size_t(std::max<int64_t>(nb, 1)));
  d.mark.fillZero(d.stream);
  launchMap(d, kept, TouchF{c.body_a.data(), c.body_b.data(), d.owner.data(), rank, d.mark.data()}, "launch of TouchF");
  Vec3 lo, hi;
  if (d.group->listedRegion(lo, hi))
    launchMap(d, nb, RegionCopyF{d.bodies.pos.data(), d.owner.data(), rank, lo, hi, d.mark.data()},
              "launch of RegionCopyF");
  const int64_t nt = selectFlagged(d, nb, d.mark.data(), "cub::DeviceSelect::Flagged (touched copies)");
  d.group->setTouchedCopies(downloadSelection(d, nt));
  const std::vector<int32_t>& list = d.group->exchangeBodies();
  d.ex_ids.upload(list, d.stream);
  reserveExchange(d, list.size());
  d.ex_count = list.size();
  preparePeerExchange(d, peer_exchange);
  DVI_CUDA(cudaStreamSynchronize(d.stream));  // the group's list may change after we return
}

void sendSharesAsync(DeviceState& d) {
  const int64_t n = int64_t(d.ex_count);
  if (n == 0) return;
  DVI_CUDA(cudaEventRecord(d.ev_shares, d.stream));
  DVI_CUDA(cudaStreamWaitEvent(d.copy_stream, d.ev_shares, 0));
  DVI_CUDA(cudaMemcpyAsync(d.ex_host, d.ex_buf.data(), sizeof(BodyDelta) * size_t(n), cudaMemcpyDeviceToHost,
                           d.copy_stream));
}

// Waits for the shares' copy alone (d.stream runs on), exchanges them, and queues their sums back into ex_buf ahead
// of whatever d.stream runs next. Returns the listed count.
static int64_t receiveSumsIntoBuffer(DeviceState& d) {
  const int64_t n = int64_t(d.ex_count);
  if (n > 0) DVI_CUDA(cudaStreamSynchronize(d.copy_stream));
  d.group->exchangeCompact(d.ex_host);  // with nothing listed: no messages (the neighbours list nothing either)
  if (n == 0) return 0;
  DVI_CUDA(cudaMemcpyAsync(d.ex_buf.data(), d.ex_host, sizeof(BodyDelta) * size_t(n), cudaMemcpyHostToDevice,
                           d.copy_stream));
  DVI_CUDA(cudaEventRecord(d.ev_sums, d.copy_stream));
  DVI_CUDA(cudaStreamWaitEvent(d.stream, d.ev_sums, 0));
  return n;
}

void receiveSums(DeviceState& d, BodyDelta* delta) {
  const int64_t n = receiveSumsIntoBuffer(d);
  launchMap(d, n, ScatterByF<BodyDelta>{d.ex_ids.data(), d.ex_buf.data(), delta}, "launch of ScatterByF (sums)");
}

void exchangeBodyValues(DeviceState& d, real* per_body) {
  const int64_t n = int64_t(d.ex_count);
  launchMap(d, n, PackValueF{d.ex_ids.data(), per_body, d.ex_buf.data()}, "launch of PackValueF");
  sendSharesAsync(d);
  receiveSumsIntoBuffer(d);
  launchMap(d, n, UnpackValueF{d.ex_ids.data(), d.ex_buf.data(), per_body}, "launch of UnpackValueF");
}

void motionBounds(DeviceState& d, real& vmax, real& wmax) {
  DeviceBodies& b = d.bodies;
  d.step_scalars.resize(16);
  auto* out = reinterpret_cast<unsigned long long*>(d.step_scalars.data());
  DVI_CUDA(cudaMemsetAsync(out, 0, 2 * sizeof(unsigned long long), d.stream));  // the bits of +0.0
  uploadOwners(d);
  const int64_t n = int64_t(b.count);
  if (n > 0) {
    motionMaxKernel<<<std::min<unsigned>(blocksFor(n), unsigned(kReduceBlocks)), kBlock, 0, d.stream>>>(
        n, b.vel.data(), b.omega.data(), d.group ? d.owner.data() : nullptr, b.flags.data(),
        d.group ? d.group->rank() : 0, out);
    DVI_CUDA_LAUNCH("motionMaxKernel");
  }
  const double* h = d.readScalars(d.step_scalars.data(), 2);
  vmax = real(h[0]);
  wmax = real(h[1]);
}

std::vector<int32_t> ownedBodiesOutside(DeviceState& d, Vec3 lo, Vec3 hi) {
  DeviceBodies& b = d.bodies;
  const int64_t n = int64_t(b.count);
  uploadOwners(d);
  d.mark.resize(size_t(std::max<int64_t>(n, 1)));
  launchMap(d, n,
            OutsideF{b.pos.data(), d.group ? d.owner.data() : nullptr, b.flags.data(), d.group ? d.group->rank() : 0,
                     lo, hi, d.mark.data()},
            "launch of OutsideF");
  return downloadSelection(d, selectFlagged(d, n, d.mark.data(), "cub::DeviceSelect::Flagged (bodies outside)"));
}

std::vector<ContactImpulse> contactImpulsesOf(DeviceState& d, const std::vector<int32_t>& bodies) {
  DeviceContacts& c = d.contacts;
  const int64_t nc = int64_t(c.count);
  std::vector<ContactImpulse> out;
  if (nc == 0 || bodies.empty() || d.solver.gamma.size() < size_t(3 * nc)) return out;
  DeviceBuffer<int32_t>& ids = d.bodies.sel_ids;
  ids.upload(bodies, d.stream);
  d.mark.resize(size_t(nc));
  launchMap(d, nc, TouchingF{c.body_a.data(), c.body_b.data(), ids.data(), int64_t(bodies.size()), d.mark.data()},
            "launch of TouchingF");
  const int64_t n = selectFlagged(d, nc, d.mark.data(), "cub::DeviceSelect::Flagged (contacts of bodies)");
  if (n == 0) return out;
  DeviceBuffer<ContactImpulse>& rec = d.impulse_records;
  rec.resize(size_t(n));
  launchMap(d, n,
            ImpulseRecordF{d.sel.data(), c.key.data(), c.body_a.data(), c.body_b.data(), d.solver.gamma.data(),
                           c.normal.data(), rec.data()},
            "launch of ImpulseRecordF");
  rec.download(out, size_t(n), d.stream);
  std::sort(out.begin(), out.end(), [](const ContactImpulse& x, const ContactImpulse& y) { return x.key < y.key; });
  return out;
}

}  // namespace dvi::gpu
