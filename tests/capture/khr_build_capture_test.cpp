// SPDX-License-Identifier: Apache-2.0
// KHR acceleration structures captured for real: tests/apps/khr_build_app builds an indexed
// triangle BLAS and an AABB BLAS from vertices it uploads with vkCmdCopyBuffer, a TLAS over two
// instances, queries compacted and serialization sizes, compacts, serializes and updates, on
// lavapipe 25 under `clastrace capture`. Each record is checked field by field against what the
// app passed (its OUT.json), and the input snapshots against the bytes the app wrote.
// Label rt-driver: skipped where lavapipe 25 is not unpacked.
#include "layer_launch_test.h"

#include <clastrace/testsupport/test_driver.h>
#include <clastrace/traces/trace_reader.h>
#include <clastrace/testsupport/trace_records.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <vulkan/vulkan_core.h>

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using namespace clastrace::layer_launch;
namespace fbs = clastrace::fbs;

constexpr uint32_t kTriangles = 0, kAabbs = 1, kInstances = 2;  // VkGeometryTypeKHR

// A snapshot with its bytes.
struct Snapshot {
    uint64_t buffer = 0, offset = 0, address = 0;
    std::vector<uint8_t> bytes;
};

// The records of one kind, packed again so they outlive the reader (object API).
struct CapturedTrace {
    std::vector<fbs::CmdBuildAccelerationStructuresKHRT> builds;
    std::vector<std::vector<Snapshot>> build_inputs;
    std::vector<fbs::CmdCopyAccelerationStructureT> copies;
    std::vector<std::vector<Snapshot>> copy_inputs;
    std::vector<fbs::CmdCopyAccelerationStructureToMemoryT> to_memory;
    std::vector<fbs::CmdWriteAccelerationStructuresPropertiesT> properties;
    std::vector<fbs::QueryPoolResultsT> results;
    std::vector<fbs::GetAccelerationStructureBuildSizesKHRT> sizes;
};

std::vector<uint8_t> bytesOf(const json& hexText) {
    const std::string text = hexText.get<std::string>();
    std::vector<uint8_t> bytes(text.size() / 2);
    for (size_t i = 0; i < bytes.size(); ++i)
        bytes[i] = uint8_t(std::stoul(text.substr(2 * i, 2), nullptr, 16));
    return bytes;
}

// The `size` bytes at `address` as one of `snapshots` holds them (empty when none does).
std::vector<uint8_t> bytesAt(const std::vector<Snapshot>& snapshots, uint64_t address,
                             size_t size) {
    for (const Snapshot& s : snapshots)
        if (s.address != 0 && s.address <= address && address + size <= s.address + s.bytes.size())
            return {s.bytes.begin() + (address - s.address),
                    s.bytes.begin() + (address - s.address + size)};
    return {};
}

class KhrBuildCapture : public RayTracingLaunchTest {
protected:
    KhrBuildCapture() : RayTracingLaunchTest("clastrace_khr_capture") {}

    void SetUp() override {
        RayTracingLaunchTest::SetUp();
        if (IsSkipped()) return;
        trace = dir / "khr.clt";
        ProcessResult r = captureOnDriver(trace, std::string(CLASTRACE_KHR_APP) + " " +
                                                     quote((dir / "out.json").string()));
        ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
        out = json::parse(readText(dir / "out.json"));
        read();
    }

    std::vector<Snapshot> snapshots(clastrace::traces::TraceReader& reader,
                                    const std::vector<fbs::MemorySnapshot>& list) {
        std::vector<Snapshot> result;
        for (const fbs::MemorySnapshot& s : list) {
            Snapshot snapshot{s.buffer(), s.offset(), s.address(), {}};
            EXPECT_FALSE(reader.read_contents(s.hash(), &snapshot.bytes));
            result.push_back(std::move(snapshot));
        }
        return result;
    }

    void read() {
        clastrace::traces::TraceError error;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
        ASSERT_TRUE(reader) << error.message;
        clastrace::traces::RecordView view;
        using clastrace::testsupport::unpack_record;
        while (reader->next(&view)) {
            if (const auto* b =
                    unpack_record<fbs::CmdBuildAccelerationStructuresKHR>(view, captured.builds))
                captured.build_inputs.push_back(snapshots(*reader, b->inputs));
            if (const auto* c =
                    unpack_record<fbs::CmdCopyAccelerationStructure>(view, captured.copies))
                captured.copy_inputs.push_back(snapshots(*reader, c->inputs));
            unpack_record<fbs::CmdCopyAccelerationStructureToMemory>(view, captured.to_memory);
            unpack_record<fbs::CmdWriteAccelerationStructuresProperties>(view, captured.properties);
            unpack_record<fbs::QueryPoolResults>(view, captured.results);
            unpack_record<fbs::GetAccelerationStructureBuildSizesKHR>(view, captured.sizes);
        }
    }

    uint64_t at(const char* object, const char* field) const {
        return out[object][field].get<uint64_t>();
    }
    std::vector<uint8_t> appBytes(const char* name) const { return bytesOf(out["bytes"][name]); }
    std::vector<uint8_t> inputAt(size_t build, const char* name, size_t size) const {
        return bytesAt(captured.build_inputs[build],
                       at("input", "address") + out["offsets"][name].get<uint64_t>(), size);
    }
    // The snapshot of a structure's storage (a KHR structure lives in its buffer).
    static const Snapshot* storageOf(const std::vector<Snapshot>& list, uint64_t buffer,
                                     uint64_t offset) {
        for (const Snapshot& s : list)
            if (s.buffer == buffer && s.offset == offset) return &s;
        return nullptr;
    }

    fs::path trace;
    json out;
    CapturedTrace captured;
};

// vkCmdBuildAccelerationStructuresKHR of the two bottom levels: both infos as the app passed them,
// and the vertex, index, transform and AABB bytes the build read (what vkCmdCopyBuffer put there).
TEST_F(KhrBuildCapture, BottomLevelBuildsHoldTheirInfosAndTheUploadedGeometry) {
    ASSERT_EQ(captured.builds.size(), 3u);
    const auto& build = captured.builds[0];
    EXPECT_FALSE(build.indirect);
    ASSERT_EQ(build.infos.size(), 2u);
    const auto& triangles = *build.infos[0];
    EXPECT_EQ(triangles.type, uint32_t(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR));
    EXPECT_EQ(triangles.flags, uint32_t(VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_COMPACTION_BIT_KHR |
                                        VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_KHR));
    EXPECT_EQ(triangles.mode, uint32_t(VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR));
    EXPECT_EQ(triangles.src, 0u);
    EXPECT_EQ(triangles.dst, at("triangleBlas", "handle"));
    EXPECT_EQ(triangles.scratch_address, out["scratch"].get<uint64_t>());
    ASSERT_EQ(triangles.geometries.size(), 1u);
    const auto& g = *triangles.geometries[0];
    EXPECT_EQ(g.geometry_type, kTriangles);
    EXPECT_EQ(g.flags, uint32_t(VK_GEOMETRY_OPAQUE_BIT_KHR));
    const uint64_t input = at("input", "address");
    EXPECT_EQ(g.triangles->vertex_format(), uint32_t(VK_FORMAT_R32G32B32_SFLOAT));
    EXPECT_EQ(g.triangles->vertex_data(), input + out["offsets"]["vertices"].get<uint64_t>());
    EXPECT_EQ(g.triangles->vertex_stride(), 12u);
    EXPECT_EQ(g.triangles->max_vertex(), 3u);
    EXPECT_EQ(g.triangles->index_type(), uint32_t(VK_INDEX_TYPE_UINT32));
    EXPECT_EQ(g.triangles->index_data(), input + out["offsets"]["indices"].get<uint64_t>());
    EXPECT_EQ(g.triangles->transform_data(), input + out["offsets"]["transform"].get<uint64_t>());
    ASSERT_EQ(triangles.ranges.size(), 1u);
    EXPECT_EQ(triangles.ranges[0].primitive_count(), 2u);
    EXPECT_EQ(triangles.ranges[0].primitive_offset(), 0u);

    const auto& boxes = *build.infos[1];
    EXPECT_EQ(boxes.dst, at("boxBlas", "handle"));
    EXPECT_EQ(boxes.flags, uint32_t(VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_KHR));
    ASSERT_EQ(boxes.geometries.size(), 1u);
    EXPECT_EQ(boxes.geometries[0]->geometry_type, kAabbs);
    EXPECT_EQ(boxes.geometries[0]->aabbs->data(), input + out["offsets"]["aabbs"].get<uint64_t>());
    EXPECT_EQ(boxes.geometries[0]->aabbs->stride(), 24u);
    ASSERT_EQ(boxes.ranges.size(), 1u);
    EXPECT_EQ(boxes.ranges[0].primitive_count(), 2u);

    EXPECT_EQ(inputAt(0, "vertices", 48), appBytes("vertices"));
    EXPECT_EQ(inputAt(0, "indices", 24), appBytes("indices"));
    EXPECT_EQ(inputAt(0, "transform", 48), appBytes("transform"));
    EXPECT_EQ(inputAt(0, "aabbs", 48), appBytes("aabbs"));
}

// The top level: its instance geometry, and the instance bytes (naming both BLAS addresses).
TEST_F(KhrBuildCapture, TopLevelBuildHoldsTheInstanceBytes) {
    ASSERT_EQ(captured.builds.size(), 3u);
    ASSERT_EQ(captured.builds[1].infos.size(), 1u);
    const auto& top = *captured.builds[1].infos[0];
    EXPECT_EQ(top.type, uint32_t(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR));
    EXPECT_EQ(top.dst, at("tlas", "handle"));
    ASSERT_EQ(top.geometries.size(), 1u);
    EXPECT_EQ(top.geometries[0]->geometry_type, kInstances);
    EXPECT_FALSE(top.geometries[0]->instances->array_of_pointers());
    EXPECT_EQ(top.geometries[0]->instances->data(), at("instances", "address"));
    ASSERT_EQ(top.ranges.size(), 1u);
    EXPECT_EQ(top.ranges[0].primitive_count(), 2u);
    const std::vector<uint8_t> instances = bytesOf(out["instances"]["bytes"]);
    EXPECT_EQ(bytesAt(captured.build_inputs[1], at("instances", "address"), instances.size()),
              instances);
}

// The update: source and destination the triangle BLAS, the moved vertices as read at execution
// (copied in the same command buffer), and the source structure's storage.
TEST_F(KhrBuildCapture, UpdateReadsTheMovedVerticesAndItsSourceStructure) {
    ASSERT_EQ(captured.builds.size(), 3u);
    const auto& update = *captured.builds[2].infos[0];
    EXPECT_EQ(update.mode, uint32_t(VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR));
    EXPECT_EQ(update.src, at("triangleBlas", "handle"));
    EXPECT_EQ(update.dst, at("triangleBlas", "handle"));
    EXPECT_EQ(inputAt(2, "vertices", 48), appBytes("movedVertices"));
    const Snapshot* source = storageOf(captured.build_inputs[2], out["storage"].get<uint64_t>(),
                                       at("triangleBlas", "offset"));
    ASSERT_NE(source, nullptr);
    EXPECT_EQ(source->bytes.size(), at("triangleBlas", "size"));
}

// Compaction size and serialization size: the queries written, and the values the app read back.
TEST_F(KhrBuildCapture, PropertyQueriesAndTheirResults) {
    ASSERT_EQ(captured.properties.size(), 2u);
    const auto& compacted = captured.properties[0];
    EXPECT_EQ(compacted.api, 1u);
    EXPECT_EQ(compacted.query_type,
              uint32_t(VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR));
    EXPECT_EQ(compacted.query_pool, out["queryPools"]["compacted"].get<uint64_t>());
    EXPECT_EQ(compacted.first_query, 0u);
    EXPECT_EQ(compacted.acceleration_structures,
              std::vector<uint64_t>{at("triangleBlas", "handle")});
    const auto& serialized = captured.properties[1];
    EXPECT_EQ(serialized.query_type,
              uint32_t(VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR));
    EXPECT_EQ(serialized.acceleration_structures, std::vector<uint64_t>{at("tlas", "handle")});

    ASSERT_EQ(captured.results.size(), 2u);
    EXPECT_EQ(captured.results[0].query_pool, out["queryPools"]["compacted"].get<uint64_t>());
    EXPECT_EQ(captured.results[0].values,
              std::vector<uint64_t>{out["compactedSize"].get<uint64_t>()});
    EXPECT_EQ(captured.results[0].result, 0);
    EXPECT_EQ(captured.results[1].query_pool, out["queryPools"]["serialized"].get<uint64_t>());
    EXPECT_EQ(captured.results[1].values,
              std::vector<uint64_t>{out["serializedSize"].get<uint64_t>()});
}

// The compacting copy reads its source's storage; the serialization names the TLAS and the
// destination address.
TEST_F(KhrBuildCapture, CompactCopyAndSerialization) {
    ASSERT_EQ(captured.copies.size(), 1u);
    const auto& copy = captured.copies[0];
    EXPECT_EQ(copy.api, 1u);
    EXPECT_EQ(copy.src, at("triangleBlas", "handle"));
    EXPECT_EQ(copy.dst, at("compact", "handle"));
    EXPECT_EQ(copy.mode, uint32_t(VK_COPY_ACCELERATION_STRUCTURE_MODE_COMPACT_KHR));
    const Snapshot* source = storageOf(captured.copy_inputs[0], out["storage"].get<uint64_t>(),
                                       at("triangleBlas", "offset"));
    ASSERT_NE(source, nullptr);
    EXPECT_EQ(source->bytes.size(), at("triangleBlas", "size"));

    ASSERT_EQ(captured.to_memory.size(), 1u);
    EXPECT_EQ(captured.to_memory[0].src, at("tlas", "handle"));
    EXPECT_EQ(captured.to_memory[0].dst_address, out["serial"].get<uint64_t>());
    EXPECT_EQ(captured.to_memory[0].mode,
              uint32_t(VK_COPY_ACCELERATION_STRUCTURE_MODE_SERIALIZE_KHR));
}

// vkGetAccelerationStructureBuildSizesKHR: the three questions and the driver's answers.
TEST_F(KhrBuildCapture, BuildSizeQueriesAndAnswers) {
    ASSERT_EQ(captured.sizes.size(), 3u);
    const char* names[3] = {"triangle", "box", "tlas"};
    const uint32_t types[3] = {kTriangles, kAabbs, kInstances};
    for (size_t i = 0; i < 3; ++i) {
        const auto& q = captured.sizes[i];
        EXPECT_EQ(q.build_type, uint32_t(VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR)) << i;
        EXPECT_EQ(q.max_primitive_counts, std::vector<uint32_t>{2}) << i;
        EXPECT_EQ(q.acceleration_structure_size, out["sizes"][names[i]].get<uint64_t>()) << i;
        ASSERT_TRUE(q.info) << i;
        ASSERT_EQ(q.info->geometries.size(), 1u) << i;
        EXPECT_EQ(q.info->geometries[0]->geometry_type, types[i]) << i;
    }
}

// Replay and info read a trace holding these records (replay may skip kinds it does not model).
TEST_F(KhrBuildCapture, ReplayAndInfoReadTheTrace) {
    ProcessResult info =
        run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " info " + quote(trace.string()), {}, false);
    EXPECT_EQ(info.exitCode, 0) << info.out << info.err;
    ProcessResult replay =
        run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " replay --json " + quote(trace.string()), {},
            false);
    EXPECT_NE(replay.exitCode, 2) << replay.out << replay.err;
}

}  // namespace
