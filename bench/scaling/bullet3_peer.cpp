// The Bullet 3 peer (bullet3_peer.h): a benchmark scene on b3GpuRigidBodyPipeline, in Bullet units = scene
// units x length_scale.
//
// The set-up follows Bullet's own GPU demos (examples/OpenCL/rigidbody/GpuRigidBodyDemo.cpp): a b3Config
// sized from the scene, b3GpuNarrowPhase, b3GpuSapBroadphase, the pipeline; shapes registered with the
// narrow phase, one physics instance per body, then writeAllInstancesToGpu / writeAllBodiesToGpu /
// writeAabbsToGpu. The OpenCL context and queue are ours (one device, checked calls); Debian's library reaches
// the same ICD loader through its built-in clew, which b3OpenCLUtils_getNumPlatforms initialises.
#include "bullet3_peer.h"

#include <unistd.h>

#include <Bullet3Collision/NarrowPhaseCollision/b3Config.h>
#include <Bullet3Collision/NarrowPhaseCollision/b3ConvexUtility.h>
#include <Bullet3Collision/NarrowPhaseCollision/shared/b3RigidBodyData.h>
#include <Bullet3Common/b3Logging.h>
#include <Bullet3Common/b3Matrix3x3.h>
#include <Bullet3OpenCL/BroadphaseCollision/b3GpuSapBroadphase.h>
#include <Bullet3OpenCL/Initialize/b3OpenCLUtils.h>
#include <Bullet3OpenCL/RigidBody/b3GpuConstraint4.h>
#include <Bullet3OpenCL/RigidBody/b3GpuNarrowPhase.h>
#include <Bullet3OpenCL/RigidBody/b3GpuNarrowPhaseInternalData.h>
#include <Bullet3OpenCL/RigidBody/b3GpuRigidBodyPipeline.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <map>
#include <mutex>
#include <sstream>

namespace dvi::bench {

namespace {

// ---------- OpenCL: checked calls ----------

const char* clErrorName(cl_int e) {
  switch (e) {
    case CL_DEVICE_NOT_FOUND: return "CL_DEVICE_NOT_FOUND";
    case CL_DEVICE_NOT_AVAILABLE: return "CL_DEVICE_NOT_AVAILABLE";
    case CL_MEM_OBJECT_ALLOCATION_FAILURE: return "CL_MEM_OBJECT_ALLOCATION_FAILURE";
    case CL_OUT_OF_RESOURCES: return "CL_OUT_OF_RESOURCES";
    case CL_OUT_OF_HOST_MEMORY: return "CL_OUT_OF_HOST_MEMORY";
    case CL_BUILD_PROGRAM_FAILURE: return "CL_BUILD_PROGRAM_FAILURE";
    case CL_INVALID_VALUE: return "CL_INVALID_VALUE";
    case CL_INVALID_PLATFORM: return "CL_INVALID_PLATFORM";
    case CL_INVALID_DEVICE: return "CL_INVALID_DEVICE";
    case CL_INVALID_CONTEXT: return "CL_INVALID_CONTEXT";
    case CL_INVALID_COMMAND_QUEUE: return "CL_INVALID_COMMAND_QUEUE";
    case CL_INVALID_MEM_OBJECT: return "CL_INVALID_MEM_OBJECT";
    case CL_INVALID_KERNEL: return "CL_INVALID_KERNEL";
    case CL_INVALID_KERNEL_ARGS: return "CL_INVALID_KERNEL_ARGS";
    case CL_INVALID_WORK_GROUP_SIZE: return "CL_INVALID_WORK_GROUP_SIZE";
    case CL_INVALID_BUFFER_SIZE: return "CL_INVALID_BUFFER_SIZE";
    case -1001: return "CL_PLATFORM_NOT_FOUND_KHR (no OpenCL driver registered with the ICD loader)";
    default: return "OpenCL error";
  }
}

void checkCl(cl_int e, const std::string& what) {
  if (e != CL_SUCCESS)
    throw Bullet3Error("OpenCL " + what + " failed: " + clErrorName(e) + " (" + std::to_string(e) + ")");
}

// A string property of an OpenCL object (clGetPlatformInfo or clGetDeviceInfo): size query, then the value.
template <class Object, class Info>
std::string clInfoString(cl_int (*get)(Object, Info, size_t, void*, size_t*), Object o, Info what, const char* name) {
  size_t n = 0;
  checkCl(get(o, what, 0, nullptr, &n), name);
  std::string s(n, '\0');
  checkCl(get(o, what, n, s.data(), nullptr), name);
  return std::string(s.c_str());
}

std::string platformString(cl_platform_id p, cl_platform_info what) {
  return clInfoString(clGetPlatformInfo, p, what, "clGetPlatformInfo");
}

std::string deviceString(cl_device_id d, cl_device_info what) {
  return clInfoString(clGetDeviceInfo, d, what, "clGetDeviceInfo");
}

template <class T>
T deviceValue(cl_device_id d, cl_device_info what) {
  T v{};
  checkCl(clGetDeviceInfo(d, what, sizeof v, &v, nullptr), "clGetDeviceInfo");
  return v;
}

struct FoundDevice {
  cl_platform_id platform = nullptr;
  cl_device_id device = nullptr;
  std::string name;
};

// The first device of `type` over all platforms (for Any: the first GPU, else the first device). Throws
// Bullet3Error saying what is missing.
FoundDevice firstDevice(OpenClDeviceType type) {
  cl_uint np = 0;
  const cl_int e = clGetPlatformIDs(0, nullptr, &np);
  if (e == -1001 || (e == CL_SUCCESS && np == 0))
    throw Bullet3Error("no OpenCL platform (no driver registered with the ICD loader in /etc/OpenCL/vendors)");
  checkCl(e, "clGetPlatformIDs");
  std::vector<cl_platform_id> platforms(np);
  checkCl(clGetPlatformIDs(np, platforms.data(), nullptr), "clGetPlatformIDs");
  std::vector<cl_device_type> wanted;
  if (type == OpenClDeviceType::Gpu || type == OpenClDeviceType::Any) wanted.push_back(CL_DEVICE_TYPE_GPU);
  if (type == OpenClDeviceType::Cpu) wanted.push_back(CL_DEVICE_TYPE_CPU);
  if (type == OpenClDeviceType::Any) wanted.push_back(CL_DEVICE_TYPE_ALL);
  std::string seen;
  for (cl_device_type t : wanted)
    for (cl_platform_id p : platforms) {
      cl_uint nd = 0;
      const cl_int de = clGetDeviceIDs(p, t, 0, nullptr, &nd);
      if (de == CL_DEVICE_NOT_FOUND || nd == 0) continue;
      checkCl(de, "clGetDeviceIDs");
      std::vector<cl_device_id> devices(nd);
      checkCl(clGetDeviceIDs(p, t, nd, devices.data(), nullptr), "clGetDeviceIDs");
      FoundDevice f{p, devices[0], ""};
      f.name = deviceString(f.device, CL_DEVICE_NAME) + " (" + platformString(p, CL_PLATFORM_NAME) + ", " +
               deviceString(f.device, CL_DEVICE_VERSION) + ")";
      return f;
    }
  for (cl_platform_id p : platforms) seen += (seen.empty() ? "" : ", ") + platformString(p, CL_PLATFORM_NAME);
  throw Bullet3Error(std::string("no OpenCL ") + (type == OpenClDeviceType::Cpu ? "CPU" : "GPU") +
                     " device (platforms: " + seen + ")");
}

// ---------- Bullet 3's messages ----------

// Bullet 3 reports its failures (capacity overflows, "OpenCL out-of-memory", kernels that do not build)
// only through b3Error, and continues; its hooks (b3Logging.h) are bare function pointers without a user
// argument. So the peer keeps one process-wide record of those messages, written by the hook and emptied
// after each call into Bullet 3: the one mutable global here, forced by that C API. b3Printf and b3Warning
// (kernel compilation chatter, cache misses) are dropped.
struct Bullet3Messages {
  std::mutex mutex;
  std::string errors;
};

Bullet3Messages& messages() {
  static Bullet3Messages m;
  return m;
}

void recordError(const char* msg) {
  Bullet3Messages& m = messages();
  std::lock_guard<std::mutex> lock(m.mutex);
  if (m.errors.size() < 4000) m.errors += msg;
}

void dropMessage(const char*) {}

void installMessageHooks() {
  b3SetCustomPrintfFunc(&dropMessage);
  b3SetCustomWarningMessageFunc(&dropMessage);
  b3SetCustomErrorMessageFunc(&recordError);
}

// The errors since the last call, as one line ("b3Error[file,line]:" headers dropped), or "".
std::string takeErrors() {
  Bullet3Messages& m = messages();
  std::string text;
  {
    std::lock_guard<std::mutex> lock(m.mutex);
    text.swap(m.errors);
  }
  std::istringstream in(text);
  std::string line, out;
  while (std::getline(in, line)) {
    while (!line.empty() && std::isspace((unsigned char)line.back())) line.pop_back();
    if (line.empty() || line.rfind("b3Error[", 0) == 0) continue;
    out += (out.empty() ? "" : "; ") + line;
  }
  if (out.size() > 300) out = out.substr(0, 300) + "...";
  return out;
}

void throwOnErrors(const std::string& when) {
  const std::string e = takeErrors();
  if (!e.empty()) throw Bullet3Error("Bullet 3 " + when + ": " + e);
}

// ---------- shapes as point sets ----------

std::vector<Vec3> boxPoints(Vec3 h) {
  std::vector<Vec3> p;
  for (int i = 0; i < 8; ++i) p.push_back(Vec3{i & 1 ? h.x : -h.x, i & 2 ? h.y : -h.y, i & 4 ? h.z : -h.z});
  return p;
}

// The points of a box or hull body (body frame, scene units); spheres are Bullet 3 spheres.
std::vector<Vec3> hullPoints(const SceneSpec& spec, const BodySpec& b) {
  if (b.kind == BodyKind::Box) return boxPoints(b.dims);
  if (b.kind != BodyKind::Hull)
    throw InputError(std::string("Bullet3Peer: no Bullet 3 shape for a ") + bodyKindName(b.kind));
  if (b.hull < 0 || size_t(b.hull) >= spec.hulls.size())
    throw InputError("Bullet3Peer: a hull body with a bad hull index");
  std::vector<Vec3> p = spec.hulls[size_t(b.hull)];
  for (Vec3& q : p) q = Vec3{q.x * b.dims.x, q.y * b.dims.y, q.z * b.dims.z};
  return p;
}

}  // namespace

bool bullet3PeerBuilt(std::string* why) {
  if (why) why->clear();
  return true;
}

bool findOpenClDevice(OpenClDeviceType type, std::string* what) {
  try {
    const FoundDevice f = firstDevice(type);
    if (what) *what = f.name;
    return true;
  } catch (const Bullet3Error& e) {
    if (what) *what = e.what();
    return false;
  }
}

struct Bullet3Peer::Impl {
  Bullet3PeerSettings settings;
  float s = 1;        // length scale
  size_t bodies = 0;  // spec.bodies.size()
  FoundDevice device;
  std::string cache_dir;  // must outlive every kernel compilation (Bullet keeps the pointer)
  cl_context context = nullptr;
  cl_command_queue queue = nullptr;
  b3Config config;
  std::vector<std::unique_ptr<b3ConvexUtility>> hulls;  // the narrow phase keeps pointers to them
  std::unique_ptr<b3GpuNarrowPhase> narrow;
  std::unique_ptr<b3GpuBroadphaseInterface> broad;
  std::unique_ptr<b3GpuRigidBodyPipeline> pipeline;
  Bullet3StepStats stats;

  ~Impl() {
    pipeline.reset();  // before the phases it points to
    broad.reset();
    narrow.reset();
    if (queue) clReleaseCommandQueue(queue);  // nothing to report from a destructor
    if (context) clReleaseContext(context);
    b3OpenCLUtils_setCachePath("cache");  // Bullet's default: cache_dir dies with this object
  }

  b3ConvexUtility* makeHull(const std::vector<Vec3>& pts) {
    std::vector<b3Vector3> v;
    for (const Vec3& p : pts) v.push_back(b3MakeVector3(float(p.x) * s, float(p.y) * s, float(p.z) * s));
    auto h = std::make_unique<b3ConvexUtility>();
    if (!h->initializePolyhedralFeatures(v.data(), int(v.size()), true))
      throw Bullet3Error("Bullet 3 could not build a convex hull of " + std::to_string(v.size()) + " points");
    hulls.push_back(std::move(h));
    return hulls.back().get();
  }

  // Bullet 3's capacities (config) for nspec bodies of which nspheres distinct sphere radii, and the hulls made.
  void setCapacities(size_t nspec, size_t nspheres, int pairs_per_body);
  // The bodies' inertia as the scene has it, in place of the one Bullet 3 made from each shape's bounding box.
  void setInertias(const SceneSpec& spec);
  void checkMemory(size_t largest, size_t total) const {
    const auto max_alloc = deviceValue<cl_ulong>(device.device, CL_DEVICE_MAX_MEM_ALLOC_SIZE);
    const auto global = deviceValue<cl_ulong>(device.device, CL_DEVICE_GLOBAL_MEM_SIZE);
    auto mib = [](double b) { return std::to_string(long(b / (1 << 20))) + " MiB"; };
    if (largest > max_alloc)
      throw Bullet3Error("Bullet 3 needs one buffer of " + mib(double(largest)) + ", more than the device's " +
                         "CL_DEVICE_MAX_MEM_ALLOC_SIZE (" + mib(double(max_alloc)) + ")");
    if (total > global)
      throw Bullet3Error("Bullet 3 needs about " + mib(double(total)) + " of device memory, the device has " +
                         mib(double(global)));
  }
};

void Bullet3Peer::Impl::setCapacities(size_t nspec, size_t nspheres, int pairs_per_body) {
  size_t faces = 1, vertices = 0, indices = 0, edges = 0, max_faces = 0;  // 1: the ground's face
  for (const auto& h : hulls) {
    faces += size_t(h->m_faces.size());
    max_faces = std::max(max_faces, size_t(h->m_faces.size()));
    vertices += size_t(h->m_vertices.size());
    edges += size_t(h->m_uniqueEdges.size());
    for (int f = 0; f < h->m_faces.size(); ++f) indices += size_t(h->m_faces[f].m_indices.size());
  }

  // Capacities from the scene (b3Config.h's defaults are for 128k bodies): every buffer Bullet 3 sizes from
  // them is allocated once here, so an overflow later is an error, not a reallocation.
  const size_t nbodies = size_t(kStaticBodies) + nspec;
  const size_t nshapes = 1 + hulls.size() + nspheres;
  b3Config& c = config;
  const double pairs = double(pairs_per_body) * double(nbodies + 8);
  if (pairs > 2e9)
    throw Bullet3Error("Bullet 3's capacities are 32-bit: " + std::to_string(nbodies) + " bodies is too many");
  c.m_maxConvexBodies = int(nbodies + 8);
  c.m_maxConvexShapes = int(nshapes + 8);
  c.m_maxBroadphasePairs = int(pairs);
  c.m_maxContactCapacity = c.m_maxBroadphasePairs;
  c.m_maxFacesPerShape = int(std::max<size_t>({12, max_faces, faces / size_t(c.m_maxConvexShapes) + 1}));
  c.m_maxConvexVertices = int(std::max<size_t>(8192, vertices + 16));
  c.m_maxConvexIndices = int(std::max<size_t>(81920, indices + 16));
  c.m_maxConvexUniqueEdges = int(std::max<size_t>(8192, edges + 16));
  // The largest buffers: two contact buffers and the solver's constraints per contact, broad-phase pairs
  // (the pipeline's and the SAP's), and three per-body clipping buffers of m_maxVerticesPerFace vertices.
  const size_t contact_bytes = size_t(c.m_maxContactCapacity) * sizeof(b3Contact4);
  const size_t clip_bytes = size_t(c.m_maxConvexBodies) * size_t(c.m_maxVerticesPerFace) * sizeof(b3Vector3);
  const size_t total = 2 * contact_bytes + size_t(c.m_maxContactCapacity) * sizeof(b3GpuConstraint4) +
                       3 * size_t(c.m_maxBroadphasePairs) * sizeof(b3Int4) + 3 * clip_bytes +
                       size_t(c.m_maxConvexShapes) * size_t(c.m_maxFacesPerShape) * sizeof(b3GpuFace);
  checkMemory(std::max(contact_bytes, clip_bytes), total);
}

void Bullet3Peer::Impl::setInertias(const SceneSpec& spec) {
  // The scene's inertia (Bullet 3 made one from each shape's bounding box), in kg x Bullet length^2.
  b3GpuNarrowPhaseInternalData* data = narrow->getInternalData();
  for (size_t i = 0; i < spec.bodies.size(); ++i) {
    const BodySpec& b = spec.bodies[i];
    const size_t id = size_t(kStaticBodies) + i;
    const float s2 = s * s;
    const b3Vector3 inv_local = b3MakeVector3(1.f / (float(b.inertia.x) * s2), 1.f / (float(b.inertia.y) * s2),
                                              1.f / (float(b.inertia.z) * s2));
    b3InertiaData& inertia = data->m_inertiaBufferCPU->at(int(id));
    inertia.m_initInvInertia.setValue(inv_local.x, 0, 0, 0, inv_local.y, 0, 0, 0, inv_local.z);
    const b3Matrix3x3 r(data->m_bodyBufferCPU->at(int(id)).m_quat);
    inertia.m_invInertiaWorld = r.scaled(inv_local) * r.transpose();
  }
}

Bullet3Peer::Bullet3Peer(const SceneSpec& scene, const Bullet3PeerSettings& settings)
    : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  const SceneSpec spec = withConvexHulls(scene);
  if (!(settings.dt > 0) || !std::isfinite(double(settings.dt)) || !(settings.length_scale > 0) ||
      !std::isfinite(double(settings.length_scale)) || settings.pairs_per_body < 1 || settings.pairs_per_body > 1024)
    throw InputError("Bullet3Peer: dt and length_scale must be positive and finite, pairs_per_body in [1, 1024]");
  m.settings = settings;
  m.s = float(settings.length_scale);
  m.bodies = spec.bodies.size();
  installMessageHooks();
  takeErrors();

  // The device, then the library's own OpenCL entry points (its clew loads the same ICD loader).
  m.device = firstDevice(settings.device);
  cl_int err = CL_SUCCESS;
  const int b3_platforms = b3OpenCLUtils_getNumPlatforms(&err);
  checkCl(err, "b3OpenCLUtils_getNumPlatforms");
  if (b3_platforms < 1) throw Bullet3Error("Bullet 3's OpenCL loader (clew) finds no platform");
  const cl_context_properties props[] = {CL_CONTEXT_PLATFORM, cl_context_properties(m.device.platform), 0};
  m.context = clCreateContext(props, 1, &m.device.device, nullptr, nullptr, &err);
  checkCl(err, "clCreateContext");
  m.queue = clCreateCommandQueue(m.context, m.device.device, 0, &err);
  checkCl(err, "clCreateCommandQueue");

  m.cache_dir =
      settings.kernel_cache_dir.empty()
          ? (std::filesystem::temp_directory_path() / ("dvisim-bullet3-kernels-" + std::to_string(getuid()))).string()
          : settings.kernel_cache_dir;
  std::error_code ec;
  std::filesystem::create_directories(m.cache_dir, ec);  // without it Bullet compiles every time, no harm
  b3OpenCLUtils_setCachePath(m.cache_dir.c_str());

  // The shapes first (hull features decide the capacities), one collidable per distinct sphere radius and
  // per hull body.
  std::vector<b3ConvexUtility*> wall_hulls;
  for (const WallSpec& w : containerWalls(spec)) wall_hulls.push_back(m.makeHull(boxPoints(w.half)));
  std::vector<b3ConvexUtility*> body_hulls(spec.bodies.size(), nullptr);
  std::map<float, int> sphere_radii;  // radius (Bullet units) -> collidable, filled below
  for (size_t i = 0; i < spec.bodies.size(); ++i) {
    const BodySpec& b = spec.bodies[i];
    if (!(b.mass > 0) || !std::isfinite(double(b.mass)) || !(b.inertia.x > 0 && b.inertia.y > 0 && b.inertia.z > 0) ||
        !std::isfinite(double(b.inertia.x + b.inertia.y + b.inertia.z)))
      throw InputError("Bullet3Peer: body " + std::to_string(i) +
                       " has a mass or inertia that is not positive and finite");
    if (b.kind == BodyKind::Sphere)
      sphere_radii[float(b.dims.x) * m.s] = -1;
    else
      body_hulls[i] = m.makeHull(hullPoints(spec, b));
  }
  m.setCapacities(spec.bodies.size(), sphere_radii.size(), settings.pairs_per_body);
  const b3Config& c = m.config;

  m.narrow = std::make_unique<b3GpuNarrowPhase>(m.context, m.device.device, m.queue, c);
  m.broad = std::make_unique<b3GpuSapBroadphase>(m.context, m.device.device, m.queue);
  m.pipeline = std::make_unique<b3GpuRigidBodyPipeline>(m.context, m.device.device, m.queue, m.narrow.get(),
                                                        m.broad.get(), nullptr, c);
  checkCl(clFinish(m.queue), "clFinish after building Bullet 3's kernels");
  throwOnErrors("failed to set up (kernels or buffers)");

  // Bodies in the order of addToSystem: the ground (body 0, Bullet's static0Index), the walls, spec.bodies.
  const float identity[4] = {0, 0, 0, 1};
  auto instance = [&](float mass, Vec3 pos, const float* orn, int collidable, const char* what) {
    if (collidable < 0)
      throw Bullet3Error(std::string("Bullet 3 refused the shape of ") + what + " (shape capacity " +
                         std::to_string(c.m_maxConvexShapes) + ")");
    const float p[4] = {float(pos.x) * m.s, float(pos.y) * m.s, float(pos.z) * m.s, 0};
    const int id = m.pipeline->registerPhysicsInstance(mass, p, orn, collidable, 0, false);
    if (id < 0)
      throw Bullet3Error(std::string("Bullet 3 refused ") + what + " (body capacity " +
                         std::to_string(c.m_maxConvexBodies) + ")");
    return id;
  };
  instance(0, Vec3{0, 0, 0}, identity, m.narrow->registerPlaneShape(b3MakeVector3(0, 1, 0), 0), "the ground");
  const std::vector<WallSpec> walls = containerWalls(spec);
  for (size_t w = 0; w < walls.size(); ++w)
    instance(0, walls[w].centre, identity, m.narrow->registerConvexHullShape(wall_hulls[w]), "a wall");
  for (auto& [radius, collidable] : sphere_radii) collidable = m.narrow->registerSphereShape(radius);
  for (size_t i = 0; i < spec.bodies.size(); ++i) {
    const BodySpec& b = spec.bodies[i];
    const float orn[4] = {float(b.rot.x), float(b.rot.y), float(b.rot.z), float(b.rot.w)};
    const int col = b.kind == BodyKind::Sphere ? sphere_radii.at(float(b.dims.x) * m.s)
                                               : m.narrow->registerConvexHullShape(body_hulls[i]);
    instance(float(b.mass), b.pos, orn, col, bodyKindName(b.kind));
  }

  m.setInertias(spec);

  m.pipeline->writeAllInstancesToGpu();
  m.narrow->writeAllBodiesToGpu();
  m.broad->writeAabbsToGpu();
  const float g[4] = {float(settings.gravity.x) * m.s, float(settings.gravity.y) * m.s, float(settings.gravity.z) * m.s,
                      0};
  m.pipeline->setGravity(g);
  checkCl(clFinish(m.queue), "clFinish after uploading the scene");
  throwOnErrors("failed to upload the scene");
}

Bullet3Peer::~Bullet3Peer() = default;

void Bullet3Peer::step() {
  Impl& m = *impl_;
  m.pipeline->stepSimulation(float(m.settings.dt));
  checkCl(clFinish(m.queue), "clFinish after a step");
  m.stats.pairs = m.broad->getNumOverlap();
  m.stats.contacts = m.narrow->getNumContactsGpu();
  if (m.stats.pairs >= m.config.m_maxBroadphasePairs)
    throw Bullet3Error("Bullet 3 ran out of broad-phase pairs (" + std::to_string(m.stats.pairs) + ", capacity " +
                       std::to_string(m.settings.pairs_per_body) + " per body)");
  if (m.stats.contacts >= m.config.m_maxContactCapacity)
    throw Bullet3Error("Bullet 3 ran out of contacts (" + std::to_string(m.stats.contacts) + ", capacity " +
                       std::to_string(m.settings.pairs_per_body) + " per body)");
  throwOnErrors("failed in a step");
}

const Bullet3StepStats& Bullet3Peer::lastStats() const { return impl_->stats; }
size_t Bullet3Peer::bodyCount() const { return impl_->bodies; }
std::string Bullet3Peer::deviceName() const { return impl_->device.name; }

std::string Bullet3Peer::description() const {
  std::ostringstream o;
  o << "b3GpuRigidBodyPipeline (SAP broad phase, PGS 4 it, mu 0.7 fixed by Bullet), "
    << (impl_->s == 100 ? std::string("cm") : "length x " + std::to_string(impl_->s))
    << ", OpenCL: " << impl_->device.name;
  return o.str();
}

void Bullet3Peer::readBodies(std::vector<Vec3>& pos, std::vector<Quat>& rot, std::vector<Vec3>& vel) const {
  const Impl& m = *impl_;
  std::vector<b3RigidBodyData> b(m.bodies);
  if (m.bodies > 0)
    checkCl(
        clEnqueueReadBuffer(m.queue, m.narrow->getBodiesGpu(), CL_TRUE, size_t(kStaticBodies) * sizeof(b3RigidBodyData),
                            m.bodies * sizeof(b3RigidBodyData), b.data(), 0, nullptr, nullptr),
        "clEnqueueReadBuffer of the bodies");
  pos.resize(m.bodies);
  rot.resize(m.bodies);
  vel.resize(m.bodies);
  for (size_t i = 0; i < m.bodies; ++i) {
    pos[i] = Vec3{real(b[i].m_pos.x / m.s), real(b[i].m_pos.y / m.s), real(b[i].m_pos.z / m.s)};
    rot[i] = Quat{real(b[i].m_quat.w), real(b[i].m_quat.x), real(b[i].m_quat.y), real(b[i].m_quat.z)};
    vel[i] = Vec3{real(b[i].m_linVel.x / m.s), real(b[i].m_linVel.y / m.s), real(b[i].m_linVel.z / m.s)};
  }
}

}  // namespace dvi::bench
