// SPDX-License-Identifier: Apache-2.0
// Serialization with the KHR header and vkCmdCopyMemoryToAccelerationStructureKHR:
// round trips (BLAS, and TLAS with the handle list patched to relocated BLAS), every
// header/size/alignment/state rule, another driver's blob, and random damage.
#include "nv_scene.h"

#include <clastrace/engine/nv_serialize.h>
#include <clastrace/testsupport/rays.h>

#include <gtest/gtest.h>

#include <cstring>
#include <random>

namespace clastrace::nvtest {
namespace {

bool has(const eng::NvDeserializeResult& r, const std::string& rule) {
    for (const auto& f : r.record.findings)
        if (f.rule == rule) return true;
    return false;
}
std::string rules(const eng::NvDeserializeResult& r) {
    std::string s;
    for (const auto& f : r.record.findings) s += f.rule + " (" + f.message + ")\n";
    return s;
}

std::vector<BlasSpec> two_blas() {
    std::vector<BlasSpec> blas(2);
    blas[0].geometries.push_back({ts::make_icosphere(2, 1.0f), {}, VK_GEOMETRY_OPAQUE_BIT_NV});
    blas[1].aabbs = true;
    blas[1].geometries.push_back({{}, random_boxes(50, 3), VK_GEOMETRY_OPAQUE_BIT_NV});
    return blas;
}

TEST(NvSerialize, HeaderLayoutIsTheKhrOne) {
    auto s = build_scene(two_blas(), random_instances(5, 2, 3.0f, 1));
    std::string error;
    const auto blob = eng::serialize_nv_object(s->world.memory, s->tlas.address, &error);
    ASSERT_FALSE(blob.empty()) << error;
    eng::SerializedHeader h;
    std::memcpy(&h, blob.data(), sizeof h);
    EXPECT_EQ(0, std::memcmp(h.driver_uuid, eng::kEngineDriverUuid.data(), 16));
    EXPECT_EQ(0, std::memcmp(h.compatibility_uuid, eng::kEngineNvCompatibilityUuid.data(), 16));
    EXPECT_EQ(h.serialized_size, blob.size());
    EXPECT_EQ(h.handle_count, 5u);
    EXPECT_EQ(h.deserialized_size, blob.size() - 56 - 5 * 8);
    uint64_t handles[5];
    std::memcpy(handles, blob.data() + 56, sizeof handles);
    auto instances = random_instances(5, 2, 3.0f, 1);
    for (int i = 0; i < 5; ++i)
        EXPECT_EQ(handles[i], s->blas[size_t(instances[size_t(i)].blas)].handle);
    const auto blas_blob = eng::serialize_nv_object(s->world.memory, s->blas[0].address, &error);
    std::memcpy(&h, blas_blob.data(), sizeof h);
    EXPECT_EQ(h.handle_count, 0u);
    EXPECT_TRUE(eng::serialize_nv_object(s->world.memory, s->instance_address, &error).empty());
    EXPECT_FALSE(error.empty());
}

TEST(NvSerialize, RoundTripRelocatesBottomLevelsThroughThePatchedHandles) {
    const auto blas = two_blas();
    const auto instances = random_instances(30, 2, 4.0f, 8);
    auto s = build_scene(blas, instances);
    ASSERT_TRUE(s->findings.empty());
    NvWorld& w = s->world;
    auto original = eng::NvScene::open(w.memory, s->tlas.address, nullptr, nullptr);
    ASSERT_TRUE(original);
    // Deserialize each BLAS into a new object, then the TLAS with its handles replaced.
    std::vector<uint64_t> moved;
    for (const auto& b : s->blas) {
        const auto blob = eng::serialize_nv_object(w.memory, b.address, nullptr);
        const uint64_t src = w.put(blob.data(), blob.size(), "blob");
        eng::NvDeserializeCommand cmd;
        cmd.src_address = src;
        cmd.dst = w.make_object(*b.created, "copy");
        const auto r = eng::execute_nv_deserialize(cmd, w.memory);
        ASSERT_TRUE(r.record.ops[0].executed) << rules(r);
        EXPECT_TRUE(r.record.findings.empty()) << rules(r);
        moved.push_back(cmd.dst.handle);
    }
    auto blob = eng::serialize_nv_object(w.memory, s->tlas.address, nullptr);
    for (size_t i = 0; i < instances.size(); ++i) {
        const uint64_t h = moved[size_t(instances[i].blas)];
        std::memcpy(blob.data() + 56 + 8 * i, &h, 8);
    }
    const uint64_t src = w.put(blob.data(), blob.size(), "tlas blob");
    eng::NvDeserializeCommand cmd;
    cmd.src_address = src;
    cmd.dst = w.make_object(*s->tlas.created, "tlas copy");
    const auto r = eng::execute_nv_deserialize(cmd, w.memory);
    ASSERT_TRUE(r.record.ops[0].executed) << rules(r);
    EXPECT_TRUE(r.record.findings.empty()) << rules(r);
    EXPECT_TRUE(r.top_level);
    ASSERT_EQ(r.record.accesses.size(), 2u);
    EXPECT_EQ(r.record.accesses[0].stage, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR);
    EXPECT_EQ(r.record.accesses[0].access, VK_ACCESS_2_TRANSFER_READ_BIT);
    EXPECT_EQ(r.record.accesses[1].access, VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    // The original BLAS are wiped: the copy can only answer through the relocated ones.
    for (const auto& b : s->blas)
        std::memset(w.memory.write_bytes(b.address, b.size, {}).data(), 0, b.size);
    auto copy = eng::NvScene::open(w.memory, cmd.dst.address, nullptr, nullptr);
    ASSERT_TRUE(copy);
    EXPECT_EQ(copy->instances_reached(), 30u);
    auto stale = eng::NvScene::open(w.memory, s->tlas.address, nullptr, nullptr);
    ASSERT_TRUE(stale);
    EXPECT_EQ(stale->instances_reached(), 0u);
    // Compare with Embree (the original is gone with its BLAS).
    EmbreeNvScene embree(blas, instances);
    Agreement a;
    ts::Bounds box;
    box.extend({-6, -6, -6});
    box.extend({6, 6, 6});
    for (const auto& tr : ts::random_rays(box, 6000, 3)) {
        const eng::Ray ray{{tr.origin[0], tr.origin[1], tr.origin[2]},
                           0.0f,
                           {tr.direction[0], tr.direction[1], tr.direction[2]},
                           tr.tmax};
        classify(a, copy->closest(ray, 0, 0xFF), embree.closest(ray, 0, 0xFF), 1e-5, "copy");
    }
    EXPECT_EQ(a.disagree, 0u) << a.summary();
    EXPECT_GT(a.agree_hit, 500u) << a.summary();
}

struct DeserializeSetup {
    std::unique_ptr<BuiltScene> s;
    std::vector<std::byte> blob;
    uint64_t src = 0;
    eng::NvDeserializeCommand cmd;
};
DeserializeSetup setup() {
    DeserializeSetup x;
    x.s = build_scene(two_blas(), random_instances(4, 2, 3.0f, 2));
    x.blob = eng::serialize_nv_object(x.s->world.memory, x.s->tlas.address, nullptr);
    std::vector<std::byte> room = x.blob;  // the blob and 512 bytes of room after it
    room.resize(x.blob.size() + 512);
    x.src = x.s->world.put(room.data(), room.size(), "blob");
    x.cmd.src_address = x.src;
    x.cmd.dst = x.s->world.make_object(*x.s->tlas.created, "dst");
    return x;
}
void patch(DeserializeSetup& x, uint64_t offset, const void* data, size_t n) {
    std::memcpy(x.s->world.memory.write_bytes(x.src + offset, n, {}).data(), data, n);
}

TEST(NvSerialize, EveryDeserializeRule) {
    {
        DeserializeSetup x = setup();
        x.cmd.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_CLONE_KHR;
        EXPECT_TRUE(
            has(eng::execute_nv_deserialize(x.cmd, x.s->world.memory), eng::kVuidDeserializeMode));
    }
    {
        DeserializeSetup x = setup();
        x.cmd.src_address = 0x10;
        EXPECT_TRUE(has(eng::execute_nv_deserialize(x.cmd, x.s->world.memory),
                        eng::kVuidDeserializeSrcAddress));
    }
    {
        DeserializeSetup x = setup();
        const std::vector<std::byte> room(x.blob.size() + 8);
        const uint64_t off = x.s->world.put(room.data(), room.size(), "unaligned") + 8;
        std::memcpy(x.s->world.memory.write_bytes(off, x.blob.size(), {}).data(), x.blob.data(),
                    x.blob.size());
        x.cmd.src_address = off;
        const auto r = eng::execute_nv_deserialize(x.cmd, x.s->world.memory);
        EXPECT_TRUE(has(r, eng::kVuidDeserializeSrcAlign)) << rules(r);
        EXPECT_TRUE(r.record.ops[0].executed);  // misaligned but readable: still decoded
    }
    {
        DeserializeSetup x = setup();
        x.cmd.dst.bound = false;
        EXPECT_TRUE(has(eng::execute_nv_deserialize(x.cmd, x.s->world.memory),
                        eng::kVuidDeserializeDstBound));
    }
    {
        DeserializeSetup x = setup();
        x.cmd.dst.size = 100;
        const auto r = eng::execute_nv_deserialize(x.cmd, x.s->world.memory);
        EXPECT_TRUE(has(r, eng::kVuidDeserializeDstSize)) << rules(r);
        EXPECT_FALSE(r.record.ops[0].executed);
    }
    {
        DeserializeSetup x = setup();  // hostile handle count
        const uint64_t n = ~0ull / 4;
        patch(x, 48, &n, 8);
        const auto r = eng::execute_nv_deserialize(x.cmd, x.s->world.memory);
        EXPECT_TRUE(has(r, eng::kVuidDeserializeContents)) << rules(r);
        EXPECT_FALSE(r.record.ops[0].executed);
    }
    {
        DeserializeSetup x = setup();  // handle count that fits the size but not the object
        const uint64_t n = 2;
        patch(x, 48, &n, 8);
        EXPECT_TRUE(has(eng::execute_nv_deserialize(x.cmd, x.s->world.memory),
                        eng::kVuidDeserializeContents));
    }
    {
        DeserializeSetup x = setup();  // serializedSize past the buffer
        const uint64_t n = x.blob.size() + 100000;
        patch(x, 32, &n, 8);
        const auto result = eng::execute_nv_deserialize(x.cmd, x.s->world.memory);
        EXPECT_TRUE(has(result, eng::kRuleDeserializeSrcPastBuffer));
        // 03744 is about contiguous binding, not the blob's size (docs/spec-readings.md).
        EXPECT_FALSE(has(result, "VUID-vkCmdCopyMemoryToAccelerationStructureKHR-pInfo-03744"));
    }
    {
        DeserializeSetup x = setup();  // damaged object bytes: a node child index out of order
        const uint64_t object = 56 + 4 * 8;
        eng::NvObjectHeader h;
        std::memcpy(&h, x.blob.data() + object, sizeof h);
        const uint32_t bad = 0;
        patch(x, object + h.nodes_offset + 12, &bad, 4);
        EXPECT_TRUE(has(eng::execute_nv_deserialize(x.cmd, x.s->world.memory),
                        eng::kVuidDeserializeContents));
    }
    {
        DeserializeSetup x = setup();  // a handle that names nothing
        const uint64_t junk = 0x7777000;
        patch(x, 56, &junk, 8);
        eng::NvDeserializeOptions o;
        o.resolve_handle = [](uint64_t h) -> std::optional<uint64_t> {
            if (h == 0x7777000) return std::nullopt;
            return h;
        };
        const auto r = eng::execute_nv_deserialize(x.cmd, x.s->world.memory, o);
        EXPECT_TRUE(has(r, eng::kRuleDeserializeHandleUnknown)) << rules(r);
        EXPECT_TRUE(r.record.ops[0].executed);
    }
    {
        DeserializeSetup x = setup();  // a top-level blob into an object created bottom-level
        x.cmd.dst = x.s->world.make_object(*x.s->blas[0].created, "blas dst");
        x.cmd.dst.size = 1 << 20;
        x.s->world.memory.add_region(x.s->world.next, 1 << 20, 0, "big");
        x.cmd.dst.address = x.s->world.next;
        x.s->world.next += 2 << 20;
        EXPECT_TRUE(has(eng::execute_nv_deserialize(x.cmd, x.s->world.memory),
                        eng::kRuleDeserializeTypeDiffers));
    }
    {
        DeserializeSetup x = setup();  // src overlapping dst
        x.cmd.dst.address = x.src + 256;
        x.cmd.dst.size = x.blob.size();
        const auto r = eng::execute_nv_deserialize(x.cmd, x.s->world.memory);
        EXPECT_TRUE(has(r, eng::kRuleDeserializeOverlap)) << rules(r);
    }
}

TEST(NvSerialize, AnotherDriversBlobIsOpaqueButChecked) {
    DeserializeSetup x = setup();
    const uint8_t uuid[16] = {0x10, 0xde, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14};
    patch(x, 0, uuid, 16);
    patch(x, 16, uuid, 16);
    auto r = eng::execute_nv_deserialize(x.cmd, x.s->world.memory);
    EXPECT_TRUE(r.opaque);
    EXPECT_TRUE(has(r, eng::kRuleSerializedOpaque)) << rules(r);
    EXPECT_FALSE(has(r, eng::kVuidDeserializeCompatible));
    EXPECT_FALSE(r.record.ops[0].executed);
    EXPECT_EQ(r.handles.size(), 4u);
    ASSERT_EQ(r.record.accesses.size(), 2u);  // the hazard checker still sees both ranges
    eng::NvDeserializeOptions o;
    o.device_compatibility_uuid = eng::Uuid{};
    std::memcpy(o.device_compatibility_uuid->data(), uuid, 16);
    EXPECT_FALSE(has(eng::execute_nv_deserialize(x.cmd, x.s->world.memory, o),
                     eng::kVuidDeserializeCompatible));
    (*o.device_compatibility_uuid)[0] ^= 1;
    EXPECT_TRUE(has(eng::execute_nv_deserialize(x.cmd, x.s->world.memory, o),
                    eng::kVuidDeserializeCompatible));
    // Its header is checked all the same.
    const uint64_t n = 1ull << 61;
    patch(x, 48, &n, 8);
    r = eng::execute_nv_deserialize(x.cmd, x.s->world.memory);
    EXPECT_TRUE(has(r, eng::kVuidDeserializeContents)) << rules(r);
}

// Random damage to a serialized TLAS: never a crash, and whatever lands in dst either
// fails to open or traces safely.
TEST(NvSerialize, RandomMutationsNeverCrash) {
    DeserializeSetup x = setup();
    std::mt19937_64 rng(77);
    size_t executed = 0, opened = 0;
    for (int round = 0; round < 1500; ++round) {
        std::vector<std::byte> m = x.blob;
        const int edits = 1 + int(rng() % 4);
        for (int e = 0; e < edits; ++e) {
            const size_t at = rng() % m.size();
            if (rng() % 3 == 0) {
                const uint64_t v = rng() % 2 ? rng() : (rng() % 512);
                std::memcpy(m.data() + std::min(at, m.size() - 8), &v, 8);
            } else {
                m[at] = std::byte(rng());
            }
        }
        patch(x, 0, m.data(), m.size());
        const auto r = eng::execute_nv_deserialize(x.cmd, x.s->world.memory);
        if (!r.record.ops[0].executed) continue;
        ++executed;
        auto scene = eng::NvScene::open(x.s->world.memory, x.cmd.dst.address, nullptr, nullptr);
        if (!scene) continue;
        ++opened;
        for (int k = 0; k < 20; ++k) {
            const eng::Ray ray{{float(rng() % 9) - 4, float(rng() % 9) - 4, 6},
                               0,
                               {0.1f, -0.05f, -1},
                               100};
            (void)scene->closest(ray, 0, 0xFF);
        }
    }
    EXPECT_GT(executed, 0u);
    EXPECT_GT(opened, 0u);
}

}  // namespace
}  // namespace clastrace::nvtest
