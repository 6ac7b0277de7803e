// SPDX-License-Identifier: Apache-2.0
// Synthetic analyzer inputs with known sizes, overlaps and timing, shared by the tests and
// the benchmark. Every number the golden tests expect is derived in the comments here.
#pragma once

#include <cstdint>
#include <string>

#include "clastrace/analyze/analyzer.h"

namespace clastrace::analyze::synthetic {

// A vkCmdBuildClusterAccelerationStructureIndirectNV, the `index`-th command of its command buffer.
inline CommandInfo cluster_command(uint64_t ordinal, uint64_t submission, uint64_t command_buffer,
                                   uint32_t index, OpType op_type, OpMode op_mode,
                                   uint64_t op_count, uint64_t triangles) {
    CommandInfo c;
    c.ordinal = ordinal;
    c.submission = submission;
    c.command_buffer = command_buffer;
    c.index = index;
    c.name = "vkCmdBuildClusterAccelerationStructureIndirectNV";
    c.op_type = op_type;
    c.op_mode = op_mode;
    c.op_count = op_count;
    c.triangles = triangles;
    return c;
}

// Three commands in two submissions:
//  cmd 0 (sub 0) build_triangle_cluster, implicit, 3 ops: implicit data 10 [0x10000,+5000),
//        scratch 11 [0x20000,+4096), src_infos 12 [0x30000,+192), dst_addresses 13 [0x31000,+24),
//        buffer 1 [0x10000,+0x40000); objects 100 @0x10000 1000 B, 101 @0x10400 1200 B,
//        102 @0x10900 1400 B (10/20/30 triangles, truncate 0/0/4, driver 1100/1300/1500);
//        query: 5000 B, scratch 2048. gpu 50 us, replay 200 us.
//  cmd 1 (sub 0) build_clusters_bottom_level, explicit, 1 op: new scratch 21 on 11's bytes
//        (reuse, 4096 B), src_infos 22 [0x30000,+16) read where 12 was read (sharing: no
//        overlap, neither writes), reads 100..102,
//        writes BLAS 200 @0x40000 800 B (60 triangles); query 1000 B/object, scratch 512.
//        gpu 20 us, replay 100 us.
//  cmd 2 (sub 1) build_triangle_cluster, implicit, 2 ops: implicit data 30 [0x10400,+2000)
//        takes 1200 B of 101 (last used by cmd 1: HAZARD, replay reports WRITE_AFTER_READ),
//        80 B of 10 (cmd 0: reuse) and 720 B of 102 (cmd 1: reuse); scratch 11 comes back on
//        21's bytes (aliasing, 4096 B). Objects 300 @0x10400 900 B (15 tris, truncate 4,
//        untruncated 1000), 301 @0x107d0 1000 B (25 tris, truncate 8, untruncated 1200).
//        query 2400 B, scratch 1024. replay 50 us, no GPU timestamp.
//  trace bytes: raw 100000, deduplicated 40000, compressed 10000.
//  GPU: 1.5 ns per tick; one timestamp span over cmds 0..1 (ticks 1000..51000: 75 us, 4 ops,
//  120 triangles); calibration tick 1000 = host 2 s, so the span starts at host 2000000000 ns.
//  One note.
inline void feed_small_scenario(Analyzer& a) {
    auto region = [&](uint64_t id, const char* label, uint64_t base, uint64_t size, RegionRole role,
                      bool written) {
        a.on_region(RegionInfo{id, label, base, size, role, written});
    };
    auto object = [&](uint32_t op, ObjectType type, uint64_t address, uint64_t bytes,
                      std::optional<uint64_t> driver, std::optional<uint64_t> untruncated,
                      uint64_t tris, uint64_t verts, uint32_t bits) {
        ObjectInfo o;
        o.op_index = op;
        o.type = type;
        o.address = address;
        o.engine_bytes = bytes;
        o.driver_bytes = driver;
        o.engine_bytes_untruncated = untruncated;
        o.triangles = tris;
        o.vertices = verts;
        o.truncate_bits = bits;
        a.on_object(o);
    };
    a.on_trace_bytes(TraceBytes{100000, 40000, 10000});
    GpuClock clock;
    clock.timestamp_period_ns = 1.5;
    clock.period_known = true;
    clock.calibration_ticks = 1000;
    clock.calibration_host_ns = 2'000'000'000;
    clock.calibration_max_deviation_ns = 100;
    a.on_gpu_clock(clock);
    a.on_gpu_span(GpuSpan{0, 1, 2, 4, 120, 1000, 75000});
    a.on_note("a note for people");

    CommandInfo c0 = cluster_command(0, 0, 7, 0, OpType::kBuildTriangleCluster,
                                     OpMode::kImplicitDestinations, 3, 60);
    c0.gpu_ns = 50000;
    c0.replay_ns = 200000;
    a.on_command(c0);
    a.on_build_sizes(BuildSizesInfo{3, 60, 72, 30, 36, 0, 5000, 2048, 0});
    region(1, "pool", 0x10000, 0x40000, RegionRole::kBuffer, false);
    region(10, "implicit A", 0x10000, 5000, RegionRole::kImplicitData, true);
    region(11, "scratch A", 0x20000, 4096, RegionRole::kScratch, true);
    region(12, "infos A", 0x30000, 192, RegionRole::kSrcInfos, false);
    region(13, "addresses A", 0x31000, 24, RegionRole::kDstAddresses, true);
    region(100, "clas 0", 0x10000, 1000, RegionRole::kObjectClas, true);
    region(101, "clas 1", 0x10400, 1200, RegionRole::kObjectClas, true);
    region(102, "clas 2", 0x10900, 1400, RegionRole::kObjectClas, true);
    object(0, ObjectType::kClas, 0x10000, 1000, 1100, std::nullopt, 10, 12, 0);
    object(1, ObjectType::kClas, 0x10400, 1200, 1300, std::nullopt, 20, 24, 0);
    object(2, ObjectType::kClas, 0x10900, 1400, 1500, std::nullopt, 30, 36, 4);

    CommandInfo c1 = cluster_command(1, 0, 7, 1, OpType::kBuildClustersBottomLevel,
                                     OpMode::kExplicitDestinations, 1, 60);
    c1.gpu_ns = 20000;
    c1.replay_ns = 100000;
    a.on_command(c1);
    a.on_build_sizes(BuildSizesInfo{1, 0, 0, 0, 0, 0, 1000, 512, 0});
    region(21, "scratch B", 0x20000, 4096, RegionRole::kScratch, true);
    region(22, "infos B", 0x30000, 16, RegionRole::kSrcInfos, false);
    region(100, "clas 0", 0x10000, 1000, RegionRole::kObjectClas, false);
    region(101, "clas 1", 0x10400, 1200, RegionRole::kObjectClas, false);
    region(102, "clas 2", 0x10900, 1400, RegionRole::kObjectClas, false);
    region(200, "blas 0", 0x40000, 800, RegionRole::kObjectBlas, true);
    object(0, ObjectType::kBlas, 0x40000, 800, std::nullopt, std::nullopt, 60, 0, 0);

    CommandInfo c2 = cluster_command(2, 1, 8, 0, OpType::kBuildTriangleCluster,
                                     OpMode::kImplicitDestinations, 2, 40);
    c2.replay_ns = 50000;
    a.on_command(c2);
    a.on_build_sizes(BuildSizesInfo{2, 40, 48, 25, 30, 4, 2400, 1024, 0});
    region(30, "implicit C", 0x10400, 2000, RegionRole::kImplicitData, true);
    region(11, "scratch A", 0x20000, 4096, RegionRole::kScratch, true);
    region(300, "clas 3", 0x10400, 900, RegionRole::kObjectClas, true);
    region(301, "clas 4", 0x107d0, 1000, RegionRole::kObjectClas, true);
    a.on_hazard(HazardSummary{
        "WRITE_AFTER_READ", 1, 2, 0x10400, 1200,
        "implicit data of cmd 2 overwrites clas 1 that cmd 1 reads, no barrier between"});
    object(0, ObjectType::kClas, 0x10400, 900, std::nullopt, 1000, 15, 18, 4);
    object(1, ObjectType::kClas, 0x107d0, 1000, std::nullopt, 1200, 25, 30, 8);
}

// A frame-like stream: `commands` commands of `ops_per_command` CLAS builds each, grouped
// `commands_per_submission` to a submission. Every frame reuses the same scratch and
// implicit-data addresses under new region ids (ordered reuse), and every 64th command a
// hazard is reported on the scratch. Object sizes cycle through 32 values.
struct StreamShape {
    uint64_t commands = 1000;
    uint64_t ops_per_command = 1000;
    uint64_t commands_per_submission = 4;
    bool with_object_regions = false;
};

inline void feed_stream(Analyzer& a, const StreamShape& shape) {
    uint64_t next_region = 1;
    for (uint64_t c = 0; c < shape.commands; ++c) {
        const uint64_t submission = c / shape.commands_per_submission;
        CommandInfo ci =
            cluster_command(c, submission, submission,
                            static_cast<uint32_t>(c % shape.commands_per_submission),
                            OpType::kBuildTriangleCluster, OpMode::kImplicitDestinations,
                            shape.ops_per_command, shape.ops_per_command * 64);
        ci.replay_ns = 1000 + (c * 7919) % 5000;
        if (c % 2 == 0) ci.gpu_ns = 500 + (c * 104729) % 3000;
        a.on_command(ci);
        const uint64_t slot = c % shape.commands_per_submission;  // per-submission address slot
        const uint64_t implicit_base = 0x100000000ull + slot * 0x10000000ull;
        const uint64_t implicit_size = shape.ops_per_command * 2048;
        a.on_build_sizes(BuildSizesInfo{shape.ops_per_command, ci.triangles, ci.triangles * 2, 64,
                                        128, 0, implicit_size, 1 << 20, 0});
        a.on_region(RegionInfo{next_region++, "implicit", implicit_base, implicit_size,
                               RegionRole::kImplicitData, true});
        a.on_region(RegionInfo{next_region++, "scratch", 0x900000000ull + slot * 0x1000000ull,
                               1 << 20, RegionRole::kScratch, true});
        uint64_t offset = 0;
        for (uint64_t op = 0; op < shape.ops_per_command; ++op) {
            ObjectInfo o;
            o.op_index = static_cast<uint32_t>(op);
            o.type = ObjectType::kClas;
            o.address = implicit_base + offset;
            o.engine_bytes = 1024 + 32 * ((c + op) % 32);
            o.triangles = 64;
            o.vertices = 96;
            o.truncate_bits = static_cast<uint32_t>(op % 3) * 4;
            if (shape.with_object_regions)
                a.on_region(RegionInfo{next_region++, "clas", o.address, o.engine_bytes,
                                       RegionRole::kObjectClas, true});
            a.on_object(o);
            offset += o.engine_bytes;
        }
        if (c >= shape.commands_per_submission && c % 64 == 0)
            a.on_hazard(HazardSummary{"WRITE_AFTER_WRITE", c - shape.commands_per_submission, c,
                                      0x900000000ull + slot * 0x1000000ull, 1 << 20,
                                      "scratch reused without a barrier"});
    }
}

}  // namespace clastrace::analyze::synthetic
