// SPDX-License-Identifier: Apache-2.0
// A ray-traced frame loop's trace for the consumer bench, shaped like examples/rt_frame_loop and
// written record by record (tests/trace_building) as the capture layer would record it on a
// driver other than the engine: per frame, the host's animated vertices copied to a device
// buffer, a barrier, one vkCmdBuildAccelerationStructuresKHR of a BLAS per mesh into the frame's
// slot of a 2-slot pool, a barrier, the TLAS build over them, a barrier, a ray-query dispatch
// (even frames) or vkCmdTraceRaysKHR (odd frames) binding the TLAS, a barrier to the host, one
// submission with the ring slot's fence and a FrameBoundary (FRAME_END). Two frames are in
// flight: frame N waits for frame N-2's fence before reusing its ring and pool slot, so the
// trace replays clean.
#pragma once

#include <cstdint>
#include <string>

namespace clastrace::bench {

struct RtFrameShape {
    uint32_t frames = 1000;
    uint32_t meshes = 2;                       // BLASes per frame (one per mesh)
    uint32_t triangles_per_mesh = 128;         // each mesh a strip of this many triangles
    uint32_t ray_width = 96, ray_height = 64;  // the consumer's launch size (as the example's)
};

struct RtFrameStats {
    uint64_t frames = 0;
    uint64_t submissions = 0;
    uint64_t file_bytes = 0;
    // What one frame brings into the replay at most: the bytes of the memory snapshots its
    // commands carry (the host-written vertices and instances). Every frame carries the same.
    uint64_t largest_frame_snapshot_bytes = 0;
    // Bytes of every buffer the frames write (2 ring slots: staging, vertices, instances,
    // scratch, TLAS; 2 pool slots of BLASes): the scene's working set, which the replay's
    // memory image may hold at once whatever the frame count.
    uint64_t working_set_bytes = 0;
};

// Writes the trace to `path`; throws std::runtime_error on a write error.
RtFrameStats write_rt_frame_trace(const std::string& path, const RtFrameShape& shape);

}  // namespace clastrace::bench
