#include "clastrace/capture/nv_scene_model.h"

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
  struct Target {
    float lo[3], hi[3];
  };
  std::vector<Target> targets;  // world bounds of the instances a ray can hit
  float sceneLo[3] = {0, 0, 0}, sceneHi[3] = {0, 0, 0};
  bool sceneBounded = false;
  uint32_t recordCount = 0;
  std::vector<int> recordKind;  // -1 unused, 0 triangles, 1 boxes
  for (size_t i = 0; i < top->second.size(); ++i) {
    const NvInstanceRecord& instance = top->second[i];
    auto blas = byDeviceHandle_.find(instance.reference);
    auto model = blas == byDeviceHandle_.end() ? bottomLevels_.end() : bottomLevels_.find(blas->second);
    if (model == bottomLevels_.end()) {
      why = "instance " + std::to_string(i) + " names bottom level handle 0x" + [&] {
        char text[32];
        std::snprintf(text, sizeof text, "%llx", (unsigned long long)instance.reference);
        return std::string(text);
      }() + ", whose build the capture did not see";
      return false;
    }
    auto [slot, inserted] = firstSlot.try_emplace(model->first, uint32_t(scene.geometryIsAabb.size()));
    if (inserted)
      for (const NvGeometryModel& g : model->second) {
        scene.geometryIsAabb.push_back(g.aabbs);
        scene.geometryFirstBox.push_back(uint32_t(scene.boxes.size() / 6));
        scene.boxes.insert(scene.boxes.end(), g.boxes.begin(), g.boxes.end());
      }
    scene.instances.push_back({instance.sbtRecordOffset, slot->second});
    const uint64_t end = uint64_t(instance.sbtRecordOffset) + model->second.size();
    if (end > kMaxRayCheckHitRecords) {
      why = "instance " + std::to_string(i) + " uses hit records up to " + std::to_string(end) + " (the check models " +
            std::to_string(kMaxRayCheckHitRecords) + ")";
      return false;
    }
    recordCount = std::max(recordCount, uint32_t(end));
    recordKind.resize(recordCount, -1);
    for (size_t g = 0; g < model->second.size(); ++g) {
      const int kind = model->second[g].aabbs ? 1 : 0;
      int& used = recordKind[instance.sbtRecordOffset + g];
      if (used >= 0 && used != kind) {
        why = "hit record " + std::to_string(instance.sbtRecordOffset + g) +
              " serves both triangle and AABB geometries (the check needs one hit group kind per record)";
        return false;
      }
      used = kind;
    }
    // World bounds: the eight corners of each bounded geometry through the instance transform.
    Target t{};
    bool bounded = false;
    for (const NvGeometryModel& g : model->second) {
      if (!g.bounded) continue;
      for (int corner = 0; corner < 8; ++corner) {
        const float p[3] = {corner & 1 ? g.hi[0] : g.lo[0], corner & 2 ? g.hi[1] : g.lo[1], corner & 4 ? g.hi[2] : g.lo[2]};
        float q[3];
        transformPoint(instance.transform, p, q);
        for (int k = 0; k < 3; ++k) {
          t.lo[k] = bounded ? std::min(t.lo[k], q[k]) : q[k];
          t.hi[k] = bounded ? std::max(t.hi[k], q[k]) : q[k];
        }
        bounded = true;
      }
    }
    if (!bounded) continue;
    for (int k = 0; k < 3; ++k) {
      sceneLo[k] = sceneBounded ? std::min(sceneLo[k], t.lo[k]) : t.lo[k];
      sceneHi[k] = sceneBounded ? std::max(sceneHi[k], t.hi[k]) : t.hi[k];
    }
    sceneBounded = true;
    if (instance.mask != 0) targets.push_back(t);
  }
  for (int kind : recordKind) scene.recordIsProcedural.push_back(kind == 1);
  if (!sceneBounded) {
    why = "no instance has bounded geometry to aim rays at";
    return false;
  }

  // Rays: even ones from a sphere around the scene at a random point of an instance's world
  // box; odd ones from random points of the scene's box (grown by half) in random directions.
  float center[3], radius = 0;
  for (int k = 0; k < 3; ++k) {
    center[k] = 0.5f * (sceneLo[k] + sceneHi[k]);
    radius = std::max(radius, 0.5f * (sceneHi[k] - sceneLo[k]));
  }
  radius = radius * 1.7320508f + 1.0f;
  Random random{0x5EEDC1A5ull ^ uint64_t(top->second.size())};
  auto unit = [&](float d[3]) {
    float len;
    do {
      for (int k = 0; k < 3; ++k) d[k] = 2.0f * random.uniform() - 1.0f;
      len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    } while (len < 0.05f || len > 1.0f);
    for (int k = 0; k < 3; ++k) d[k] /= len;
  };
  for (uint32_t i = 0; i < rayCount; ++i) {
    NvTracedRay r{};
    float d[3];
    if (i % 2 == 0 && !targets.empty()) {
      const Target& t = targets[(i / 2) % targets.size()];
      float onSphere[3], aim[3];
      unit(onSphere);
      for (int k = 0; k < 3; ++k) {
        r.origin[k] = center[k] + 2.0f * radius * onSphere[k];
        aim[k] = t.lo[k] + (t.hi[k] - t.lo[k]) * random.uniform();
        d[k] = aim[k] - r.origin[k];
      }
      const float len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      for (int k = 0; k < 3; ++k) d[k] = len > 0 ? d[k] / len : (k == 1 ? -1.0f : 0.0f);
    } else {
      for (int k = 0; k < 3; ++k) {
        const float half = 0.75f * (sceneHi[k] - sceneLo[k]) + 0.5f;
        r.origin[k] = center[k] - half + 2.0f * half * random.uniform();
      }
      unit(d);
    }
    for (int k = 0; k < 3; ++k) {
      // No exact zero component: the AABB shader's slab test divides by it.
      if (d[k] == 0.0f) d[k] = 1e-7f;
      r.direction[k] = d[k];
    }
    r.tMin = (i % 16 == 7) ? 0.5f * radius : 0.0f;
    r.tMax = (i % 16 == 11) ? 2.5f * radius : 8.0f * radius;
    r.rayFlags = 0;
    r.cullMask = (i % 8 == 5) ? 0x01u : 0xFFu;
    rays.push_back(r);
  }
  return true;
}

}  // namespace clastrace::capture
