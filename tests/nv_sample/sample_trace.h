// SPDX-License-Identifier: Apache-2.0
// Reads one of the H100 NV samples (traces/samples/h100_nv_*.clt) into plain lists the tests
// assert on: NV objects and handles, the NV builds with their input bytes, the
// deserializations with their blob, the ray checks.
#pragma once

#include <clastrace/traces/trace_reader.h>
#include <vulkan/vulkan.h>

#include <gtest/gtest.h>

#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

namespace clastrace::nv_sample {

struct Sample {
    std::unique_ptr<traces::TraceReader> reader;
    std::map<uint64_t, uint64_t>
        nvHandles;  // acceleration structure -> vkGetAccelerationStructureHandleNV
    std::set<uint64_t> khrObjects, boundObjects;
    struct Build {
        bool topLevel = false, update = false;
        uint64_t dst = 0, src = 0;
        uint32_t geometries = 0, instances = 0;
        std::map<uint64_t, std::vector<uint8_t>> inputs;  // by hash
        std::vector<uint32_t> geometryTypes;
    };
    std::vector<Build> builds;
    struct Copy {
        uint64_t dst = 0;
        uint32_t mode = 0;
        std::vector<uint8_t> blob;
    };
    std::vector<Copy> copies;
    struct Check {
        uint64_t as = 0, handle = 0, after = 0;
        std::vector<fbs::TracedRay> rays;
        std::vector<fbs::RayHitResult> results;
        std::string label;
    };
    std::vector<Check> checks;
    uint64_t submissions = 0;
};

inline std::vector<uint8_t> contents(traces::TraceReader& reader, const fbs::MemorySnapshot* s) {
    std::vector<uint8_t> bytes;
    EXPECT_FALSE(reader.read_contents(s->hash(), &bytes)) << "contents " << s->hash();
    return bytes;
}

inline Sample loadSample(const std::string& path) {
    {
        Sample out;
        traces::TraceError error;
        out.reader = traces::TraceReader::open(path, &error);
        if (!out.reader) return out;
        traces::RecordView view;
        auto& reader = *out.reader;
        while (reader.next(&view)) {
            const fbs::Record* r = view.record;
            switch (view.kind) {
            case fbs::RecordBody::AccelerationStructureCreate: {
                auto* c = r->body_as_AccelerationStructureCreate();
                if (c->api() == 0)
                    out.nvHandles[c->acceleration_structure()] = c->device_address();
                else
                    out.khrObjects.insert(c->acceleration_structure());
                break;
            }
            case fbs::RecordBody::AccelerationStructureBindMemory:
                out.boundObjects.insert(
                    r->body_as_AccelerationStructureBindMemory()->acceleration_structure());
                break;
            case fbs::RecordBody::CmdBuildAccelerationStructureNV: {
                auto* c = r->body_as_CmdBuildAccelerationStructureNV();
                Sample::Build b;
                b.topLevel = c->info()->type() == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
                b.update = c->update();
                b.dst = c->dst();
                b.src = c->src();
                b.instances = c->info()->instance_count();
                if (c->info()->geometries()) {
                    b.geometries = c->info()->geometries()->size();
                    for (auto* g : *c->info()->geometries())
                        b.geometryTypes.push_back(g->geometry_type());
                }
                if (c->inputs())
                    for (auto* s : *c->inputs()) b.inputs[s->hash()] = contents(reader, s);
                out.builds.push_back(std::move(b));
                break;
            }
            case fbs::RecordBody::CmdCopyMemoryToAccelerationStructure: {
                auto* c = r->body_as_CmdCopyMemoryToAccelerationStructure();
                Sample::Copy copy{c->dst(), c->mode(), {}};
                if (c->inputs() && c->inputs()->size() == 1)
                    copy.blob = contents(reader, c->inputs()->Get(0));
                out.copies.push_back(std::move(copy));
                break;
            }
            case fbs::RecordBody::RayQueryCheck: {
                auto* c = r->body_as_RayQueryCheck();
                Sample::Check check{c->acceleration_structure(),
                                    c->device_handle(),
                                    c->after_submission(),
                                    {},
                                    {},
                                    {}};
                if (c->rays())
                    for (auto* ray : *c->rays()) check.rays.push_back(*ray);
                if (c->results())
                    for (auto* result : *c->results()) check.results.push_back(*result);
                if (c->label()) check.label = c->label()->str();
                out.checks.push_back(std::move(check));
                break;
            }
            case fbs::RecordBody::QueueSubmit: ++out.submissions; break;
            default: break;
            }
        }
        return out;
    }
}


}  // namespace clastrace::nv_sample
