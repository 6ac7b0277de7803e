// SPDX-License-Identifier: Apache-2.0
// Writes traces of VK_KHR_acceleration_structure programs as the capture layer records them
// (khr_records.h), with the NV and cluster builds a top level may name: buffers with device
// addresses, KHR objects in their buffers, builds with the bytes they read, copies, property
// queries, and ray checks whose "driver" answers the test states.
#pragma once

#include <clastrace/engine/khr_build.h>
#include <clastrace/replay/replay_report.h>
#include <clastrace/trace_building/record_writer.h>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace clastrace::khrtest {

// A ray and the hit the "driver" reported for it (RayQueryCheck).
struct CheckedRay {
    std::array<float, 3> origin;
    std::array<float, 3> direction;
    bool hit = true;
    float t = 0.0f;
    uint32_t instance = 0;
    uint32_t primitive = 0;
    uint32_t hit_kind = 0xFF;
    float u = 0.0f, v = 0.0f;
};

class KhrTrace {
public:
    // engine_device: the trace claims the engine captured it (addresses are the engine's).
    KhrTrace(const std::string& path, bool engine_device);

    // A bound buffer with a device address; `bytes` (when given) are snapshotted into the
    // next command's inputs.
    uint64_t buffer(const void* bytes, uint64_t size, uint64_t usage);
    uint64_t address_of(uint64_t buffer) const;

    struct Object {
        uint64_t handle = 0;
        uint64_t address = 0;  // KHR: device address; NV: the driver handle
    };
    Object create(VkAccelerationStructureTypeKHR type, uint64_t size = 1 << 16);
    // A KHR bottom level over one triangle (0,0,0) (1,0,0) (0,1,0); vertices in a new buffer
    // unless `vertex_buffer` is given.
    engine::KhrBuildInfo triangle_blas(const Object& dst, uint64_t vertex_buffer = 0);
    // A KHR top level over `instances` (64-byte records) written in a new buffer.
    engine::KhrBuildInfo top_level(const Object& dst,
                                   const std::vector<std::array<uint8_t, 64>>& instances);
    void build(const engine::KhrBuildCommand& command);
    // An NV bottom level over the same triangle (create, requirements, bind, build).
    Object nv_triangle_blas();
    // A cluster BLAS over the same triangle, through a CLAS build and a BLAS build with
    // explicit destinations; `null_reference` adds a second, null, cluster reference.
    // Returns the BLAS address. `driver_address` != 0: the BLAS is built in implicit mode and
    // the capture saw the driver write that address into dstAddressesArray (returned).
    uint64_t cluster_triangle_blas(bool null_reference = false, uint64_t driver_address = 0);

    void copy_buffer(uint64_t src, uint64_t dst, uint64_t size);
    void barrier(uint64_t src_stages, uint64_t src_access, uint64_t dst_stages,
                 uint64_t dst_access);
    void build_barrier();  // AS writes -> AS reads and builds
    template <class Body>
    void command(Body body) {
        begin_if_needed();
        writer_.append(std::move(body));
    }
    template <class Body>
    void host(Body body) {
        writer_.append(std::move(body));
    }
    void submit();
    void ray_check(const Object& tlas, const std::vector<CheckedRay>& rays);
    replay::ReplayReport replay();

    uint64_t command_buffer() const { return command_buffer_; }

private:
    void begin_if_needed();
    std::vector<fbs::MemorySnapshot> take_inputs();
    uint64_t scratch();

    std::string path_;
    trace_building::RecordWriter writer_;
    std::vector<fbs::MemorySnapshot> pending_;
    std::vector<std::pair<uint64_t, uint64_t>> buffers_;  // handle, address
    uint64_t next_buffer_ = 0xB000, next_address_ = 0x10000000, next_object_ = 0xA5000;
    uint64_t command_buffer_ = 0xC0DE;
    bool open_ = false;
};

// The triangle the helpers build, and a ray through it from z = -5 at (x, y).
std::vector<float> triangle_vertices();
CheckedRay ray_through(float x, float y, uint32_t instance);

size_t count_rule(const replay::ReplayReport& r, const std::string& rule);
std::string describe(const replay::ReplayReport& r);

}  // namespace clastrace::khrtest
