// SPDX-License-Identifier: Apache-2.0
// Traces for the analyzer's golden tests, written with the TraceWriter: cluster builds whose
// sizes the engine computes here (a mirror of the replay), build-sizes answers, GPU timestamps,
// a legacy NV build and a deserialization, on buffers at fixed addresses so tests can name
// every byte the report should show.
#pragma once

#include <clastrace/trace_building/engine_mirror.h>
#include <clastrace/trace_building/record_writer.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace clastrace::test {

struct AnalyzeScene {
    static constexpr uint64_t kVertices = 0x10000000, kIndices = 0x10010000, kInfos = 0x10020000,
                              kArrays =
                                  0x10030000,  // dstAddressesArray / dstSizesArray, 0x400 per build
        kPool = 0x10100000, kPoolSize = 0x40000,  // implicit data and scratch
        kSerialized = 0x10200000, kAsStorage = 0x10300000;
    static constexpr uint64_t kPoolBuffer = 0x2005, kVertexBuffer = 0x2001, kIndexBuffer = 0x2002,
                              kAsBuffer = 0x2008;
    static constexpr uint64_t kNvObject = 0xa5, kKhrObject = 0xb7;
};

struct ClusterBuild {
    std::vector<uint32_t>
        triangle_counts;  // one cluster per entry, a strip of n triangles on n + 2 vertices
    uint32_t truncate_bits = 0;
    uint64_t dst = AnalyzeScene::kPool;  // dstImplicitData
    uint64_t scratch = AnalyzeScene::kPool + 0x20000;
    uint64_t arrays = AnalyzeScene::kArrays;  // dstAddressesArray; dstSizesArray at +0x200
    uint32_t driver_extra_bytes = 128;        // the "driver" reports engine size + this
    bool query = true;                        // a GetClusterBuildSizes record before the build
    uint64_t query_answer = 0x10000;          // its acceleration_structure_size
    uint64_t query_scratch = 0x1000;          // its build_scratch_size
    // Explicit: op i's object goes to dst + i * 1024 (dstAddressesArray and dstSizesArray = 1024
    // are inputs). Compute sizes: only dstSizesArray is written.
    VkClusterAccelerationStructureOpModeNV mode =
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
};

struct BuiltClusters {
    std::vector<uint64_t> engine_sizes;  // per op
    uint64_t implicit_used = 0, scratch_used = 0;
    uint64_t triangles = 0, vertices = 0;
};

class AnalyzeSceneWriter {
public:
    AnalyzeSceneWriter(const std::string& path, float timestamp_period_ns);
    ~AnalyzeSceneWriter();

    BuiltClusters build(const ClusterBuild& build);
    void timestamp(uint64_t ticks);
    void build_to_build_barrier();
    void
    copy_buffer();  // a vkCmdCopyBuffer of 256 bytes past the arrays (work for a timestamp span)
    // vkCmdBuildAccelerationStructureNV of one indexed triangle geometry (index_count / 3
    // triangles); memory requirements: object `object_bytes`, build scratch `scratch_bytes`.
    void nv_build(uint32_t index_count, uint64_t object_bytes, uint64_t scratch_bytes);
    // vkCmdCopyMemoryToAccelerationStructureKHR of `serialized_bytes` into a KHR object of `object_bytes`.
    void deserialize(uint64_t serialized_bytes, uint64_t object_bytes);
    void calibrate(uint64_t gpu_ticks, uint64_t host_ns, uint64_t max_deviation_ns);
    void submit();  // ends the command buffer and submits it; later commands go into a fresh one
    traces::TraceWriterStats finish();

private:
    trace_building::EngineMirror mirror_;
    trace_building::RecordWriter writer_;
    uint64_t command_buffer_ = 0xc0de;
    bool nv_declared_ = false, khr_declared_ = false;
    void add_buffer(uint64_t handle, uint64_t address, uint64_t size, uint64_t usage);
    void begin();
};

}  // namespace clastrace::test
