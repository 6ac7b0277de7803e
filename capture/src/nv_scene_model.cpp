#include "clastrace/capture/nv_scene_model.h"
#include <clastrace/common/hex.h>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace clastrace::capture {
namespace {

const CapturedRange* findRange(const std::vector<CapturedRange>& inputs, MemoryRole role, uint32_t entry) {
  for (const auto& r : inputs)
    if (r.role == role && r.entry == entry) return &r;
  return nullptr;
}

float readFloat(const CapturedBytes& bytes, size_t offset) {
  float f = 0;
  if (offset + 4 <= bytes.size()) std::memcpy(&f, bytes.data() + offset, 4);
  return f;
}

void grow(NvGeometryModel& g, const float p[3]) {
  for (int k = 0; k < 3; ++k) {
    if (!std::isfinite(p[k])) return;
  }
  for (int k = 0; k < 3; ++k) {
    g.lo[k] = g.bounded ? std::min(g.lo[k], p[k]) : p[k];
    g.hi[k] = g.bounded ? std::max(g.hi[k], p[k]) : p[k];
  }
  g.bounded = true;
}

void transformPoint(const float m[12], const float p[3], float out[3]) {
  for (int r = 0; r < 3; ++r) out[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
}

// splitmix64: the same rays for the same scene on every machine.
struct Random {
  uint64_t state;
  uint64_t next() {
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  float uniform() { return float(next() >> 40) / float(1 << 24); }
};

// An axis-aligned box in world space, empty until its first point.
struct WorldBox {
  float lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  bool bounded = false;
};

// The eight corners of each bounded geometry of a bottom level through the instance transform.
WorldBox instanceWorldBox(const NvInstanceRecord& instance, const std::vector<NvGeometryModel>& geometries) {
  WorldBox t;
  for (const NvGeometryModel& g : geometries) {
    if (!g.bounded) continue;
    for (int corner = 0; corner < 8; ++corner) {
      const float p[3] = {corner & 1 ? g.hi[0] : g.lo[0], corner & 2 ? g.hi[1] : g.lo[1], corner & 4 ? g.hi[2] : g.lo[2]};
      float q[3];
      transformPoint(instance.transform, p, q);
      for (int k = 0; k < 3; ++k) {
        t.lo[k] = t.bounded ? std::min(t.lo[k], q[k]) : q[k];
        t.hi[k] = t.bounded ? std::max(t.hi[k], q[k]) : q[k];
      }
      t.bounded = true;
    }
  }
  return t;
}

void growBox(WorldBox& into, const WorldBox& box) {
  for (int k = 0; k < 3; ++k) {
    into.lo[k] = into.bounded ? std::min(into.lo[k], box.lo[k]) : box.lo[k];
    into.hi[k] = into.bounded ? std::max(into.hi[k], box.hi[k]) : box.hi[k];
  }
  into.bounded = true;
}

// A bottom level's geometries join the scene's geometry table the first time an instance names
// it; returns the slot of its geometry 0.
uint32_t geometrySlotOf(uint64_t bottomLevel, const std::vector<NvGeometryModel>& geometries,
                        std::map<uint64_t, uint32_t>& firstSlot, NvTraceScene& scene) {
  auto [slot, inserted] = firstSlot.try_emplace(bottomLevel, uint32_t(scene.geometryIsAabb.size()));
  if (inserted)
    for (const NvGeometryModel& g : geometries) {
      scene.geometryIsAabb.push_back(g.aabbs);
      scene.geometryFirstBox.push_back(uint32_t(scene.boxes.size() / 6));
      scene.boxes.insert(scene.boxes.end(), g.boxes.begin(), g.boxes.end());
    }
  return slot->second;
}

// Marks the hit records the instance's geometries use as triangle (0) or box (1) records in
// `recordKind` (-1: unused); false + `why` past the modelled records or on a record used by both.
bool claimHitRecords(const NvInstanceRecord& instance, size_t instanceIndex,
                     const std::vector<NvGeometryModel>& geometries, std::vector<int>& recordKind, std::string& why) {
  const uint64_t end = uint64_t(instance.sbtRecordOffset) + geometries.size();
  if (end > kMaxRayCheckHitRecords) {
    why = "instance " + std::to_string(instanceIndex) + " uses hit records up to " + std::to_string(end) +
          " (the check models " + std::to_string(kMaxRayCheckHitRecords) + ")";
    return false;
  }
  recordKind.resize(std::max(recordKind.size(), size_t(end)), -1);
  for (size_t g = 0; g < geometries.size(); ++g) {
    const int kind = geometries[g].aabbs ? 1 : 0;
    int& used = recordKind[instance.sbtRecordOffset + g];
    if (used >= 0 && used != kind) {
      why = "hit record " + std::to_string(instance.sbtRecordOffset + g) +
            " serves both triangle and AABB geometries (the check needs one hit group kind per record)";
      return false;
    }
    used = kind;
  }
  return true;
}

// Where the rays start and what they aim at.
struct RayAim {
  std::vector<WorldBox> targets;  // world boxes of the instances a ray can hit
  WorldBox scene;
  float center[3] = {0, 0, 0};
  float radius = 0;
};

void randomUnitVector(Random& random, float d[3]) {
  float len;
  do {
    for (int k = 0; k < 3; ++k) d[k] = 2.0f * random.uniform() - 1.0f;
    len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  } while (len < 0.05f || len > 1.0f);
  for (int k = 0; k < 3; ++k) d[k] /= len;
}

// From a sphere around the scene towards a random point of `target`.
void aimAtTarget(const RayAim& aim, const WorldBox& target, Random& random, NvTracedRay& r, float d[3]) {
  float onSphere[3], point[3];
  randomUnitVector(random, onSphere);
  for (int k = 0; k < 3; ++k) {
    r.origin[k] = aim.center[k] + 2.0f * aim.radius * onSphere[k];
    point[k] = target.lo[k] + (target.hi[k] - target.lo[k]) * random.uniform();
    d[k] = point[k] - r.origin[k];
  }
  const float len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  for (int k = 0; k < 3; ++k) d[k] = len > 0 ? d[k] / len : (k == 1 ? -1.0f : 0.0f);
}

// From a random point of the scene's box (grown by half) in a random direction.
void aimAnywhere(const RayAim& aim, Random& random, NvTracedRay& r, float d[3]) {
  for (int k = 0; k < 3; ++k) {
    const float half = 0.75f * (aim.scene.hi[k] - aim.scene.lo[k]) + 0.5f;
    r.origin[k] = aim.center[k] - half + 2.0f * half * random.uniform();
  }
  randomUnitVector(random, d);
}

// Even rays come from a sphere around the scene at a random point of an instance's world box;
// odd ones from random points of the scene's box (grown by half) in random directions.
void aimRays(RayAim& aim, uint32_t rayCount, uint64_t seed, std::vector<NvTracedRay>& rays) {
  for (int k = 0; k < 3; ++k) {
    aim.center[k] = 0.5f * (aim.scene.lo[k] + aim.scene.hi[k]);
    aim.radius = std::max(aim.radius, 0.5f * (aim.scene.hi[k] - aim.scene.lo[k]));
  }
  aim.radius = aim.radius * 1.7320508f + 1.0f;
  Random random{seed};
  for (uint32_t i = 0; i < rayCount; ++i) {
    NvTracedRay r{};
    float d[3];
    if (i % 2 == 0 && !aim.targets.empty()) aimAtTarget(aim, aim.targets[(i / 2) % aim.targets.size()], random, r, d);
    else aimAnywhere(aim, random, r, d);
    for (int k = 0; k < 3; ++k) {
      // No exact zero component: the AABB shader's slab test divides by it.
      if (d[k] == 0.0f) d[k] = 1e-7f;
      r.direction[k] = d[k];
    }
    r.tMin = (i % 16 == 7) ? 0.5f * aim.radius : 0.0f;
    r.tMax = (i % 16 == 11) ? 2.5f * aim.radius : 8.0f * aim.radius;
    r.rayFlags = 0;
    r.cullMask = (i % 8 == 5) ? 0x01u : 0xFFu;
    rays.push_back(r);
  }
}


}  // namespace

void NvSceneModel::setHandle(uint64_t accelerationStructure, uint64_t deviceHandle) {
  std::lock_guard lock(mutex_);
  byDeviceHandle_[deviceHandle] = accelerationStructure;
  deviceHandles_[accelerationStructure] = deviceHandle;
}

void NvSceneModel::forget(uint64_t accelerationStructure) {
  std::lock_guard lock(mutex_);
  bottomLevels_.erase(accelerationStructure);
  topLevels_.erase(accelerationStructure);
  auto it = deviceHandles_.find(accelerationStructure);
  if (it == deviceHandles_.end()) return;
  byDeviceHandle_.erase(it->second);
  deviceHandles_.erase(it);
}

void NvSceneModel::observeBuild(const BuildAccelerationStructureNVCommand& c, const std::vector<CapturedRange>& inputs) {
  if (c.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV) {
    std::vector<NvInstanceRecord> instances;
    if (const CapturedRange* r = findRange(inputs, MemoryRole::Instances, 0))
      for (size_t at = 0; at + 64 <= r->bytes.size(); at += 64) {
        NvInstanceRecord i;
        const uint8_t* p = r->bytes.data() + at;
        std::memcpy(i.transform, p, 48);
        uint32_t a, b;
        std::memcpy(&a, p + 48, 4);
        std::memcpy(&b, p + 52, 4);
        std::memcpy(&i.reference, p + 56, 8);
        i.customIndex = a & 0xFFFFFF;
        i.mask = a >> 24;
        i.sbtRecordOffset = b & 0xFFFFFF;
        i.flags = b >> 24;
        instances.push_back(i);
      }
    std::lock_guard lock(mutex_);
    topLevels_[c.dst] = std::move(instances);
    return;
  }
  std::vector<NvGeometryModel> geometries(c.geometries.size());
  for (uint32_t g = 0; g < c.geometries.size(); ++g) {
    NvGeometryModel& model = geometries[g];
    const VkGeometryNV& geometry = c.geometries[g];
    if (geometry.geometryType == VK_GEOMETRY_TYPE_AABBS_NV) {
      model.aabbs = true;
      const auto& a = geometry.geometry.aabbs;
      const CapturedRange* r = findRange(inputs, MemoryRole::Aabbs, g);
      const uint64_t stride = a.stride ? a.stride : 24;
      for (uint32_t i = 0; r && i < a.numAABBs; ++i) {
        const size_t at = size_t(i) * stride;
        float box[6];
        for (int k = 0; k < 6; ++k) box[k] = readFloat(r->bytes, at + 4 * k);
        model.boxes.insert(model.boxes.end(), box, box + 6);
        grow(model, box);
        grow(model, box + 3);
      }
      continue;
    }
    const auto& t = geometry.geometry.triangles;
    const CapturedRange* vertices = findRange(inputs, MemoryRole::VertexBuffer, g);
    const int components = t.vertexFormat == VK_FORMAT_R32G32B32_SFLOAT ? 3 : t.vertexFormat == VK_FORMAT_R32G32_SFLOAT ? 2 : 0;
    if (!vertices || components == 0) continue;  // unbounded: rays are not aimed at it
    const uint64_t stride = t.vertexStride ? t.vertexStride : uint64_t(components) * 4;
    float transform[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    if (const CapturedRange* m = findRange(inputs, MemoryRole::TransformData, g); m && m->bytes.size() >= 48)
      std::memcpy(transform, m->bytes.data(), 48);
    for (uint32_t v = 0; v < t.vertexCount; ++v) {
      const size_t at = size_t(v) * stride;
      if (at + size_t(components) * 4 > vertices->bytes.size()) break;
      float p[3] = {readFloat(vertices->bytes, at), readFloat(vertices->bytes, at + 4),
                    components == 3 ? readFloat(vertices->bytes, at + 8) : 0.0f};
      float q[3];
      transformPoint(transform, p, q);
      grow(model, q);
    }
  }
  std::lock_guard lock(mutex_);
  bottomLevels_[c.dst] = std::move(geometries);
}

bool NvSceneModel::prepare(uint64_t topLevel, uint32_t rayCount, NvTraceScene& scene, std::vector<NvTracedRay>& rays,
                           uint64_t& deviceHandle, std::string& why) const {
  std::lock_guard lock(mutex_);
  scene = {};
  rays.clear();
  auto top = topLevels_.find(topLevel);
  if (top == topLevels_.end()) {
    why = "its build's instance records were not captured";
    return false;
  }
  auto handle = deviceHandles_.find(topLevel);
  deviceHandle = handle == deviceHandles_.end() ? 0 : handle->second;

  std::map<uint64_t, uint32_t> firstSlot;  // bottom level -> its geometry 0's slot
  RayAim aim;
  std::vector<int> recordKind;  // -1 unused, 0 triangles, 1 boxes
  for (size_t i = 0; i < top->second.size(); ++i) {
    const NvInstanceRecord& instance = top->second[i];
    auto blas = byDeviceHandle_.find(instance.reference);
    auto model = blas == byDeviceHandle_.end() ? bottomLevels_.end() : bottomLevels_.find(blas->second);
    if (model == bottomLevels_.end()) {
      why = "instance " + std::to_string(i) + " names bottom level handle " + common::hex(instance.reference) +
            ", whose build the capture did not see";
      return false;
    }
    scene.instances.push_back({instance.sbtRecordOffset, geometrySlotOf(model->first, model->second, firstSlot, scene)});
    if (!claimHitRecords(instance, i, model->second, recordKind, why)) return false;
    const WorldBox box = instanceWorldBox(instance, model->second);
    if (!box.bounded) continue;
    growBox(aim.scene, box);
    if (instance.mask != 0) aim.targets.push_back(box);
  }
  for (int kind : recordKind) scene.recordIsProcedural.push_back(kind == 1);
  if (!aim.scene.bounded) {
    why = "no instance has bounded geometry to aim rays at";
    return false;
  }
  aimRays(aim, rayCount, 0x5EEDC1A5ull ^ uint64_t(top->second.size()), rays);
  return true;
}

}  // namespace clastrace::capture
