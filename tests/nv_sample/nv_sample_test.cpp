// SPDX-License-Identifier: Apache-2.0
// traces/samples/h100_nv_ray_tracing.clt: nv_ray_tracing_app captured under the layer on an
// NVIDIA H100 (traces/samples/README.md). Checks that the trace holds what replay needs: the
// device and its driver identity, the NV objects with their handles and memory, every NV build
// with its inputs as executed, the deserialization with the driver's blob, and the ray checks.
#include "sample_trace.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <map>
#include <set>

namespace {

using namespace clastrace;
using namespace clastrace::nv_sample;

constexpr uint32_t kRays = 4096;  // CLASTRACE_RAY_CHECK the sample was made with
const uint32_t kCustomIndex[5] = {10, 11, 12, 0xABCDE, 14};  // per instance, as the app sets them

const Sample& sample() {
    static const Sample s = loadSample(CLASTRACE_NV_SAMPLE);
    return s;
}

TEST(NvSample, OpensWithoutDamageAndIsSmall) {
    const Sample& s = sample();
    ASSERT_TRUE(s.reader) << CLASTRACE_NV_SAMPLE;
    EXPECT_TRUE(s.reader->has_index());
    EXPECT_EQ(s.reader->damage_count(), 0u);
    EXPECT_LT(s.reader->stats().file_size, 2u << 20);
}

TEST(NvSample, HeaderDescribesTheH100AndItsDriver) {
    const Sample& s = sample();
    ASSERT_TRUE(s.reader && s.reader->header() && s.reader->header()->device());
    const fbs::DeviceInfo* d = s.reader->header()->device();
    ASSERT_TRUE(d->name());
    EXPECT_NE(d->name()->str().find("H100"), std::string::npos) << d->name()->str();
    EXPECT_EQ(d->vendor_id(), 0x10DEu);
    EXPECT_EQ(d->driver_id(), uint32_t(VK_DRIVER_ID_NVIDIA_PROPRIETARY));
    ASSERT_TRUE(d->driver_name());
    EXPECT_EQ(d->driver_name()->str(), "NVIDIA");  // a native capture, not the layer's engine
    ASSERT_TRUE(d->driver_uuid());
    EXPECT_EQ(d->driver_uuid()->size(), 16u);
    ASSERT_TRUE(d->ray_tracing_properties_nv());
    EXPECT_GT(d->ray_tracing_properties_nv()->shader_group_handle_size(), 0u);
    EXPECT_GT(d->ray_tracing_properties_nv()->max_instance_count(), 4u);
    ASSERT_TRUE(d->enabled_extensions());
    std::set<std::string> extensions;
    for (auto* e : *d->enabled_extensions()) extensions.insert(e->str());
    EXPECT_TRUE(extensions.count("VK_NV_ray_tracing"));
    EXPECT_TRUE(extensions.count("VK_KHR_acceleration_structure"));
}

TEST(NvSample, NvObjectsHaveHandlesAndMemory) {
    const Sample& s = sample();
    ASSERT_EQ(s.nvHandles.size(), 3u);  // triangle and AABB bottom levels, top level
    for (const auto& [as, handle] : s.nvHandles) {
        EXPECT_NE(handle, 0u) << as;
        EXPECT_TRUE(s.boundObjects.count(as)) << as;
    }
    EXPECT_EQ(s.khrObjects.size(), 2u);  // the serialized source and the deserialized copy
}

TEST(NvSample, BuildsThenRefitsBothBottomLevelsAndTheTopLevel) {
    const Sample& s = sample();
    ASSERT_EQ(s.builds.size(), 6u);
    for (size_t i = 0; i < 6; ++i) {
        const auto& b = s.builds[i];
        EXPECT_EQ(b.update, i >= 3) << i;
        EXPECT_EQ(b.src, b.update ? b.dst : 0u) << i;
        EXPECT_TRUE(s.nvHandles.count(b.dst)) << i;
        EXPECT_EQ(b.dst, s.builds[i % 3].dst) << i;
    }
    // Triangles: two geometries (vertices+indices+transform for the first, vertices+indices for
    // the second) = 5 distinct inputs; AABBs: one geometry; top level: 5 instance records.
    EXPECT_EQ(s.builds[0].geometryTypes, (std::vector<uint32_t>{VK_GEOMETRY_TYPE_TRIANGLES_NV,
                                                                VK_GEOMETRY_TYPE_TRIANGLES_NV}));
    EXPECT_EQ(s.builds[0].inputs.size(), 5u);
    EXPECT_EQ(s.builds[1].geometryTypes, (std::vector<uint32_t>{VK_GEOMETRY_TYPE_AABBS_NV}));
    ASSERT_EQ(s.builds[1].inputs.size(), 1u);
    EXPECT_EQ(s.builds[1].inputs.begin()->second.size(), 7u * 32 + 24);  // 8 boxes, stride 32
    EXPECT_TRUE(s.builds[2].topLevel);
    EXPECT_EQ(s.builds[2].instances, 5u);
    ASSERT_EQ(s.builds[2].inputs.size(), 1u);
    // The instance records name the bottom levels by their NV handles.
    const auto& records = s.builds[2].inputs.begin()->second;
    ASSERT_EQ(records.size(), 5u * 64);
    for (int i = 0; i < 5; ++i) {
        uint64_t reference;
        uint32_t custom;
        std::memcpy(&reference, records.data() + 64 * i + 56, 8);
        std::memcpy(&custom, records.data() + 64 * i + 48, 4);
        EXPECT_EQ(reference, s.nvHandles.at(s.builds[(i == 2 || i == 3) ? 1 : 0].dst)) << i;
        EXPECT_EQ(custom & 0xFFFFFF, kCustomIndex[i]) << i;
    }
    // The refit read moved inputs: its vertices, boxes and instances differ from the build's.
    EXPECT_NE(s.builds[3].inputs, s.builds[0].inputs);
    EXPECT_NE(s.builds[4].inputs, s.builds[1].inputs);
    EXPECT_NE(s.builds[5].inputs, s.builds[2].inputs);
}

TEST(NvSample, DeserializationCarriesTheDriversBlob) {
    const Sample& s = sample();
    ASSERT_EQ(s.copies.size(), 1u);
    const auto& c = s.copies[0];
    EXPECT_EQ(c.mode, uint32_t(VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR));
    EXPECT_TRUE(s.khrObjects.count(c.dst));
    ASSERT_GE(c.blob.size(), 56u);
    uint64_t serialized, deserialized, handles;
    std::memcpy(&serialized, c.blob.data() + 32, 8);
    std::memcpy(&deserialized, c.blob.data() + 40, 8);
    std::memcpy(&handles, c.blob.data() + 48, 8);
    EXPECT_EQ(serialized, c.blob.size());  // the whole blob, as its header sizes it
    EXPECT_GT(deserialized, 0u);
    EXPECT_EQ(handles, 0u);  // a bottom level names no other structure
    // The blob is the capturing driver's: its header starts with the device's driver UUID.
    const fbs::DeviceInfo* d = s.reader->header()->device();
    ASSERT_TRUE(d->driver_uuid() && d->driver_uuid()->size() == 16);
    EXPECT_EQ(std::memcmp(c.blob.data(), d->driver_uuid()->data(), 16), 0);
}

TEST(NvSample, RayChecksFollowTheBuildAndTheRefit) {
    const Sample& s = sample();
    ASSERT_EQ(s.checks.size(), 2u);
    const uint64_t topLevel = s.builds[2].dst;
    std::set<uint64_t> after;
    for (const auto& c : s.checks) {
        EXPECT_EQ(c.as, topLevel);
        EXPECT_EQ(c.handle, s.nvHandles.at(topLevel));
        EXPECT_LT(c.after, s.submissions);
        after.insert(c.after);
        EXPECT_NE(c.label.find("clastrace-ray-check/1"), std::string::npos) << c.label;
        ASSERT_EQ(c.rays.size(), kRays);
        ASSERT_EQ(c.results.size(), kRays);
    }
    EXPECT_EQ(after.size(), 2u);
}

TEST(NvSample, DriverAnswersArePlausible) {
    const Sample& s = sample();
    for (const auto& c : s.checks) {
        uint32_t hits = 0, triangleHits = 0, boxHits = 0, tetrahedronHits = 0;
        std::set<uint32_t> instances;
        for (size_t i = 0; i < c.results.size(); ++i) {
            const auto& ray = c.rays[i];
            const auto& h = c.results[i];
            ASSERT_LE(h.hit(), 1u);
            if (!h.hit()) continue;
            ++hits;
            ASSERT_LT(h.instance_id(), 5u) << i;
            EXPECT_NE(h.instance_id(), 4u) << "instance 4 has mask 0";
            EXPECT_EQ(h.instance_custom_index(), kCustomIndex[h.instance_id()]) << i;
            EXPECT_GE(h.t(), ray.t_min()) << i;
            EXPECT_LE(h.t(), ray.t_max()) << i;
            instances.insert(h.instance_id());
            const bool boxes = h.instance_id() == 2 || h.instance_id() == 3;
            if (boxes) {
                ++boxHits;
                EXPECT_EQ(h.hit_kind(), 0u) << i;
                EXPECT_EQ(h.geometry_index(), 0u) << i;
                EXPECT_LT(h.primitive_id(), 8u) << i;
            } else {
                ++triangleHits;
                EXPECT_TRUE(h.hit_kind() == 0xFEu || h.hit_kind() == 0xFFu)
                    << i << " " << h.hit_kind();
                EXPECT_LT(h.geometry_index(), 2u) << i;
                tetrahedronHits += h.geometry_index() == 1;
                EXPECT_LT(h.primitive_id(), h.geometry_index() == 0 ? 72u : 4u) << i;
                EXPECT_GE(h.barycentric_u(), 0.0f);
                EXPECT_GE(h.barycentric_v(), 0.0f);
                EXPECT_LE(h.barycentric_u() + h.barycentric_v(), 1.0001f);
            }
        }
        // Half the rays are aimed at an instance's world box: many hit, not all.
        EXPECT_GT(hits, kRays / 5);
        EXPECT_LT(hits, kRays);
        EXPECT_GT(triangleHits, 100u);
        EXPECT_GT(boxHits, 100u);
        EXPECT_EQ(instances.size(), 4u);
        EXPECT_GT(tetrahedronHits, 0u);  // geometry 1 of the triangle bottom level
    }
}

}  // namespace
