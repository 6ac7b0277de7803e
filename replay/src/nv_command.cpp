// SPDX-License-Identifier: Apache-2.0
// vkCmdBuildAccelerationStructureNV / vkCmdCopyMemoryToAccelerationStructureKHR replay and
// the RayQueryCheck comparison (nv_command.hpp).
#include "nv_command.h"

#include "cluster_command.h"  // hex()

#include <clastrace/engine/nv_serialize.h>
#include <clastrace/engine/nv_trace.h>
#include <clastrace/traces/utf8_text.h>

#include <algorithm>
#include <chrono>
#include <cmath>

namespace clastrace::replay::detail {
namespace {

constexpr uint64_t kWholeSize = ~0ull;
constexpr VkBufferUsageFlags kRayTracingUsage = VK_BUFFER_USAGE_RAY_TRACING_BIT_NV;

// Vulkan's "inactive instance" is reference 0; anything the app wrote there that names no
// created object is the driver's (and the engine's) undefined behaviour.
constexpr const char* kRuleUnknownObject = "CLASTRACE-replay-nv-unknown-object";
constexpr const char* kRuleShadowBudget = "CLASTRACE-replay-nv-object-over-budget";
constexpr const char* kRuleOpaqueObject = "CLASTRACE-replay-nv-opaque-object";
constexpr const char* kRuleRayDisagrees = "CLASTRACE-replay-ray-check-disagrees";
constexpr const char* kRuleUnknownBuffer = "CLASTRACE-replay-nv-buffer-not-bound";
// t agreement between the driver and the engine (float hardware vs double): relative.
constexpr double kRayCheckRelT = 1e-5;

struct Resolved {
    uint64_t address = 0;
    uint64_t available = kWholeSize;
    VkBufferUsageFlags usage = 0;  // 0: unknown
};

engine::NvObjectInfo counts_of(const fbs::AccelerationStructureInfoNV* info) {
    engine::NvObjectInfo out;
    if (!info) return out;
    out.type = VkAccelerationStructureTypeNV(info->type());
    out.flags = info->flags();
    out.instance_count = info->instance_count();
    if (info->geometries())
        for (const fbs::GeometryNV* g : *info->geometries()) {
            engine::NvGeometry geo;
            geo.type = VkGeometryTypeNV(g->geometry_type());
            geo.flags = g->flags();
            if (const fbs::GeometryTrianglesNV* t = g->triangles()) {
                geo.triangles.vertex_count = t->vertex_count();
                geo.triangles.vertex_format = VkFormat(t->vertex_format());
                geo.triangles.vertex_stride = t->vertex_stride();
                geo.triangles.vertex_offset = t->vertex_offset();
                geo.triangles.index_count = t->index_count();
                geo.triangles.index_type = VkIndexType(t->index_type());
                geo.triangles.index_offset = t->index_offset();
                geo.triangles.transform_offset = t->transform_offset();
            }
            if (const fbs::GeometryAabbNV* a = g->aabbs()) {
                geo.aabbs.count = a->num_aabbs();
                geo.aabbs.stride = a->stride();
                geo.aabbs.offset = a->offset();
            }
            out.geometries.push_back(geo);
        }
    return out;
}

enum class DisagreementCause { kFarTiny, kDegenerate, kUnexplained };

// Why a ray's answers may honestly differ: a NaN or zero direction or a hit whose float32 error
// bound is unbounded (degenerate geometry); a hit whose float32 error is large against the
// comparison's tolerances, or a ray from far away (|origin| or the hit distance over 1e4 of
// the direction: float ulps there reach 1e-3), where a float pipeline's rounding decides
// (far/tiny); otherwise unexplained.
DisagreementCause disagreement_cause(const engine::Ray& ray, const engine::NvHit& e,
                                     const fbs::RayHitResult& d) {
    const float dmax = std::max(
        {std::fabs(ray.direction[0]), std::fabs(ray.direction[1]), std::fabs(ray.direction[2])});
    bool nan = !(dmax > 0.0f);
    for (int a = 0; a < 3; ++a) nan |= std::isnan(ray.origin[a]) || std::isnan(ray.direction[a]);
    if (nan || (e.hit && !std::isfinite(e.uv_error))) return DisagreementCause::kDegenerate;
    if (e.hit && (e.t_error > 1e-4f * std::fabs(e.t) || e.uv_error > 1e-3f))
        return DisagreementCause::kFarTiny;
    const float omax =
        std::max({std::fabs(ray.origin[0]), std::fabs(ray.origin[1]), std::fabs(ray.origin[2])});
    const float t = std::max(e.hit ? e.t : 0.0f, d.hit() ? d.t() : 0.0f);
    if (omax > 1e4f || t * dmax > 1e4f) return DisagreementCause::kFarTiny;
    return DisagreementCause::kUnexplained;
}

const char* cause_name(DisagreementCause c) {
    switch (c) {
    case DisagreementCause::kFarTiny: return "far/tiny";
    case DisagreementCause::kDegenerate: return "NaN/degenerate";
    case DisagreementCause::kUnexplained: break;
    }
    return "unexplained";
}

// One ray's answers compared: agreements, ties and edge cases counted in `out`; returns the
// kind of a disagreement, or nullptr when the answers agree.
const char* compare_answers(const engine::NvHit& e, const fbs::RayHitResult& d,
                            RayCheckResult& out) {
    const bool driver_hit = d.hit() != 0;
    auto near_edge = [](float u, float v, uint32_t kind) {
        return (kind == engine::kHitKindFrontFacing || kind == engine::kHitKindBackFacing) &&
               std::min({u, v, 1.0f - u - v}) < 1e-5f;
    };
    const char* verdict = nullptr;  // a disagreement's kind; nullptr when the answers agree
    if (!e.hit && !driver_hit) {
        ++out.agree_miss;
    } else if (e.hit && driver_hit) {
        const double rel =
            std::fabs(double(e.t) - d.t()) / std::max(std::fabs(double(d.t())), 1e-30);
        const bool same =
            e.instance_index == d.instance_id() && e.primitive_index == d.primitive_id() &&
            (d.geometry_index() == 0xFFFFFFFFu || d.geometry_index() == e.geometry_index);
        // A driver traces in float32: within the engine's bound of that error, the same
        // primitive at a t off by more than kRayCheckRelT still agrees (counted apart).
        const bool within_float = std::fabs(double(e.t) - d.t()) <= double(e.t_error);
        if (same && (rel <= kRayCheckRelT || within_float)) {
            // Barycentrics within 1e-3, or within their float32 error bound (a tiny
            // triangle far away: float noise on both sides), counted apart as t is.
            const float du = std::fabs(e.u - d.barycentric_u()),
                        dv = std::fabs(e.v - d.barycentric_v());
            const bool uv_close = du <= 1e-3f && dv <= 1e-3f;
            const bool uv_within_float = du <= e.uv_error && dv <= e.uv_error;
            const bool attributes = e.instance_custom_index == d.instance_custom_index() &&
                                    e.hit_kind == d.hit_kind() &&
                                    (e.hit_kind == 0 || uv_close || uv_within_float);
            if (attributes) {
                ++out.agree_hit;
                if (rel > kRayCheckRelT || (e.hit_kind != 0 && !uv_close))
                    ++out.float_precision;
                else
                    out.max_rel_t = std::max(out.max_rel_t, rel);
            } else {
                verdict = "same primitive and t, other custom index, hit kind or barycentrics";
            }
        } else if (rel <= kRayCheckRelT) {
            ++out.tie;
        } else if (near_edge(e.u, e.v, e.hit_kind) ||
                   near_edge(d.barycentric_u(), d.barycentric_v(), d.hit_kind())) {
            ++out.edge;
        } else {
            verdict = same ? "same primitive, other t" : "other primitive at another t";
        }
    } else if ((e.hit && near_edge(e.u, e.v, e.hit_kind)) ||
               (driver_hit && near_edge(d.barycentric_u(), d.barycentric_v(), d.hit_kind()))) {
        ++out.edge;
    } else {
        verdict =
            e.hit ? "the engine hits, the driver missed" : "the driver hit, the engine misses";
    }
    return verdict;
}

std::string disagreement_message(size_t i, const std::string& label, const engine::Ray& ray,
                                 const fbs::TracedRay& r, const fbs::RayHitResult& d,
                                 const engine::NvHit& e, const char* verdict,
                                 DisagreementCause cause, const std::string& traversal) {
    const bool driver_hit = d.hit() != 0;
    char text[768];
    std::snprintf(text, sizeof text,
                  "ray %zu of check '%s' (origin %g %g %g, direction %g %g %g, t [%g, %g], "
                  "flags 0x%x, cull mask 0x%x): %s (cause class %s, %s traversal); "
                  "driver: %s t=%g instance %u primitive %u kind 0x%x u %g v %g; engine: %s "
                  "t=%g instance %u primitive %u kind 0x%x u %g v %g (float32 error of u, v "
                  "%g)",
                  i, label.c_str(), ray.origin[0], ray.origin[1], ray.origin[2], ray.direction[0],
                  ray.direction[1], ray.direction[2], ray.tmin, ray.tmax, r.ray_flags(),
                  r.cull_mask(), verdict, cause_name(cause), traversal.c_str(),
                  driver_hit ? "hit" : "miss", double(d.t()), d.instance_id(), d.primitive_id(),
                  d.hit_kind(), double(d.barycentric_u()), double(d.barycentric_v()),
                  e.hit ? "hit" : "miss", double(e.t), e.instance_index, e.primitive_index,
                  e.hit_kind, double(e.u), double(e.v), double(e.uv_error));
    return text;
}

}  // namespace

NvReplay::Object* NvReplay::object(uint64_t handle) {
    auto it = objects_.find(handle);
    return it == objects_.end() ? nullptr : &it->second;
}

void NvReplay::set_device(const fbs::DeviceInfo& device) {
    if (const fbs::RayTracingPropertiesNV* p = device.ray_tracing_properties_nv()) {
        if (p->max_geometry_count()) limits_.max_geometry_count = p->max_geometry_count();
        if (p->max_instance_count()) limits_.max_instance_count = p->max_instance_count();
        if (p->max_triangle_count()) limits_.max_triangle_count = p->max_triangle_count();
    }
    // The accelerationStructure feature cannot be enabled without its extension.
    if (const auto* extensions = device.enabled_extensions();
        extensions && extensions->size() > 0) {
        khr_acceleration_structure_missing_ = true;
        for (const flatbuffers::String* e : *extensions)
            if (e && e->str() == "VK_KHR_acceleration_structure")
                khr_acceleration_structure_missing_ = false;
    }
}

void NvReplay::on_create(const fbs::AccelerationStructureCreate& create) {
    Object o;
    o.handle = create.acceleration_structure();
    o.nv = create.api() == 0;
    if (o.nv) {
        o.created = counts_of(create.info());
    } else {
        o.bound = create.buffer() != 0;  // KHR objects live in a buffer
        o.khr_size = create.size();
    }
    o.driver_handle = create.device_address();
    if (o.driver_handle) by_driver_handle_[o.driver_handle] = o.handle;
    objects_[o.handle] = std::move(o);
}

void NvReplay::on_requirement(const fbs::AccelerationStructureMemoryRequirementsNV& r) {
    Object* o = object(r.acceleration_structure());
    if (!o) return;
    switch (r.type()) {
    case VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_OBJECT_NV:
        o->driver_object = r.size();
        break;
    case VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_BUILD_SCRATCH_NV:
        o->driver_build_scratch = r.size();
        break;
    case VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_UPDATE_SCRATCH_NV:
        o->driver_update_scratch = r.size();
        break;
    default: break;
    }
}

void NvReplay::on_bind(const fbs::AccelerationStructureBindMemory& bind) {
    if (Object* o = object(bind.acceleration_structure())) o->bound = true;
}

bool NvReplay::ensure_shadow(Object& o, const ReplayLocation& where, uint64_t at_least) {
    uint64_t need = o.created ? engine::nv_memory_requirements(*o.created).object : 0;
    need = std::max({need, o.khr_size, at_least, uint64_t(engine::kNvObjectAlignment)});
    if (o.shadow && o.shadow_size >= need) return true;
    const uint64_t budget = std::min(kShadowBudget, c_.options.memory_budget_bytes / 2);
    if (need > budget || next_shadow_ - kShadowBase > budget - need) {
        c_.add_finding({kRuleShadowBudget,
                        "acceleration structure " + hex(o.handle) + " would need " +
                            std::to_string(need) +
                            " bytes of engine memory; all NV objects together may take " +
                            std::to_string(budget) +
                            " (half of ReplayOptions::memory_budget_bytes, at most 4 GiB)",
                        FindingSource::kReplay, where, -1, 0});
        return false;
    }
    // A larger object than the shadow holds (a deserialization) moves it: instance records
    // built earlier keep naming the old bytes, as a driver's would.
    o.shadow = next_shadow_;
    o.shadow_size = need;
    c_.memory.image().add_region(o.shadow, need, 0, "engine NV object " + hex(o.handle));
    next_shadow_ += (need + engine::kNvObjectAlignment - 1) / engine::kNvObjectAlignment *
                        engine::kNvObjectAlignment +
                    4096;
    shadow_owner_[o.shadow] = o.handle;
    return true;
}

engine::NvObjectBinding NvReplay::binding(Object& o, const ReplayLocation& where) {
    engine::NvObjectBinding b;
    b.handle = o.handle;
    b.bound = o.bound;
    b.created = o.created;
    b.built = o.built;
    b.built_flags = o.built_flags;
    if (o.bound && ensure_shadow(o, where)) {
        b.address = o.shadow;
        b.size = o.shadow_size;
    } else {
        b.bound = false;
    }
    return b;
}

std::optional<uint64_t> NvReplay::resolve(uint64_t driver_handle, bool bottom_only) {
    auto it = by_driver_handle_.find(driver_handle);
    if (it == by_driver_handle_.end()) return std::nullopt;
    Object* o = object(it->second);
    if (!o) return std::nullopt;
    if (bottom_only && o->created &&
        o->created->type != VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV)
        return std::nullopt;
    if (!o->bound || !ensure_shadow(*o, ReplayLocation{})) return std::nullopt;
    ++c_.report.counts.handles_translated;
    return o->shadow;
}

void NvReplay::engine_findings(const engine::ExecutionRecord& record, const ReplayLocation& where) {
    for (const engine::Finding& f : record.findings)
        c_.add_finding({f.rule, f.message, FindingSource::kEngine, where, f.op_index, f.address});
}

void NvReplay::feed(const CommandRef& ref, const engine::ExecutionRecord& record,
                    const ReplayLocation&) {
    if (!c_.options.check_hazards) return;
    for (const engine::MemoryAccess& a : record.accesses) {
        AddressRange range{a.begin, a.end};
        if (a.begin >= kShadowBase) {
            // The engine's bytes stand for the captured object's memory.
            auto it = shadow_owner_.upper_bound(a.begin);
            if (it == shadow_owner_.begin()) continue;
            auto captured = c_.memory.object_range(std::prev(it)->second);
            if (!captured) continue;
            range = *captured;
        }
        if (range.empty()) continue;
        ++c_.report.counts.accesses;
        c_.sync.record_access(ref, Access{range, a.stage, a.access, a.is_write, a.field});
    }
}

namespace {

// A buffer and offset as a build names them: the address, the bytes from there to the buffer's
// end and its usage; a finding when no bound buffer has that handle.
Resolved resolve_buffer(NvReplayContext& c, uint64_t handle, uint64_t offset,
                        const std::string& field, const ReplayLocation& where) {
    if (handle == 0) return {};
    auto whole = c.memory.buffer_range(handle, 0, kWholeSize);
    if (!whole) {
        c.add_finding(
            {kRuleUnknownBuffer,
             field + " names buffer " + hex(handle) + ", which is not bound to memory in the trace",
             FindingSource::kReplay, where, -1, 0});
        return {0, 0, 0};
    }
    Resolved r;
    const uint64_t size = whole->end - whole->begin;
    r.address = whole->begin + offset;
    r.available = offset >= size ? 0 : size - offset;
    if (const engine::MemoryRegion* region = c.memory.image().find_region(whole->begin))
        r.usage = region->usage;
    return r;
}

void resolve_geometries(NvReplayContext& c, const fbs::CmdBuildAccelerationStructureNV& b,
                        engine::NvBuildCommand& cmd, const ReplayLocation& where) {
    if (!b.info() || !b.info()->geometries()) return;
    uint32_t g = 0;
    for (const fbs::GeometryNV* geo : *b.info()->geometries()) {
        engine::NvGeometry& out = cmd.info.geometries[g];
        const std::string at = "pInfo->pGeometries[" + std::to_string(g++) + "]";
        if (const fbs::GeometryTrianglesNV* t = geo->triangles();
            t && out.type == VK_GEOMETRY_TYPE_TRIANGLES_NV) {
            Resolved v =
                resolve_buffer(c, t->vertex_data(), t->vertex_offset(), at + ".vertexData", where);
            out.triangles.vertex_address = v.address;
            out.triangles.vertex_available = v.available;
            Resolved i =
                resolve_buffer(c, t->index_data(), t->index_offset(), at + ".indexData", where);
            out.triangles.index_address = i.address;
            out.triangles.index_available = i.available;
            Resolved m = resolve_buffer(c, t->transform_data(), t->transform_offset(),
                                        at + ".transformData", where);
            out.triangles.transform_address = m.address;
            out.triangles.transform_available = m.available;
        }
        if (const fbs::GeometryAabbNV* a = geo->aabbs();
            a && out.type == VK_GEOMETRY_TYPE_AABBS_NV) {
            Resolved r = resolve_buffer(c, a->aabb_data(), a->offset(), at + ".aabbData", where);
            out.aabbs.address = r.address;
            out.aabbs.available = r.available;
        }
    }
}

// The build's geometries, instances and scratch, by address.
void resolve_inputs(NvReplayContext& c, const fbs::CmdBuildAccelerationStructureNV& b,
                    engine::NvBuildCommand& cmd, const ReplayLocation& where) {
    cmd.info = counts_of(b.info());
    resolve_geometries(c, b, cmd, where);
    const Resolved instances =
        resolve_buffer(c, b.instance_data(), b.instance_offset(), "instanceData", where);
    cmd.instance_address = instances.address;
    cmd.instance_available = instances.available;
    cmd.instance_buffer_ray_tracing_usage =
        instances.usage == 0 || (instances.usage & kRayTracingUsage);
    const Resolved scratch = resolve_buffer(c, b.scratch(), b.scratch_offset(), "scratch", where);
    cmd.scratch_address = scratch.address;
    cmd.scratch_available = scratch.available;
    cmd.scratch_ray_tracing_usage = scratch.usage == 0 || (scratch.usage & kRayTracingUsage);
    cmd.update = b.update();
}

// With the capturing driver's scratch requirement in the trace, the scratch rule is that one:
// the engine ran with the whole buffer, its scratch access is cut to what the driver needs of
// the `available` bytes, and too few of them is a finding.
void apply_driver_scratch(engine::ExecutionRecord& record, const engine::NvBuildCommand& cmd,
                          uint64_t available, uint64_t driver_scratch) {
    for (engine::MemoryAccess& a : record.accesses)
        if (a.field == "scratch") a.end = a.begin + std::min(available, driver_scratch);
    if (driver_scratch <= available) return;
    record.findings.push_back(
        engine::Finding{cmd.update ? engine::kVuidNvUpdateScratch : engine::kVuidNvBuildScratch,
                        "scratch holds " + std::to_string(available) +
                            " bytes after scratchOffset; the driver's " +
                            (cmd.update ? "update" : "build") + " scratch requirement is " +
                            std::to_string(driver_scratch),
                        -1, cmd.scratch_address});
}

}  // namespace

NvReplay::Object* NvReplay::bind_build_structures(const fbs::CmdBuildAccelerationStructureNV& b,
                                                  engine::NvBuildCommand& cmd,
                                                  const ReplayLocation& where) {
    Object* dst = object(b.dst());
    if (!dst) {
        c_.add_finding({kRuleUnknownObject,
                        "dst " + hex(b.dst()) + " was never created in the trace",
                        FindingSource::kReplay, where, -1, 0});
        cmd.dst.handle = b.dst();
    } else {
        cmd.dst = binding(*dst, where);
    }
    if (b.src() != 0) {
        if (Object* src = object(b.src()))
            cmd.src = binding(*src, where);
        else {
            c_.add_finding({kRuleUnknownObject,
                            "src " + hex(b.src()) + " was never created in the trace",
                            FindingSource::kReplay, where, -1, 0});
            cmd.src.handle = b.src();
        }
    }
    return dst;
}

void NvReplay::note_sizes(const Object& dst, const engine::NvBuildCommand& cmd,
                          const engine::ExecutionRecord& record, const ReplayLocation& where) {
    NvSizeComparison s;
    s.where = where;
    s.handle = dst.handle;
    s.top_level = cmd.info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    const engine::NvMemoryRequirements need =
        engine::nv_memory_requirements(dst.created ? *dst.created : cmd.info);
    s.primitives = s.top_level ? cmd.info.instance_count : 0;
    for (const engine::NvGeometry& g : cmd.info.geometries)
        s.primitives += g.type == VK_GEOMETRY_TYPE_AABBS_NV ? g.aabbs.count
                        : g.triangles.index_type == VK_INDEX_TYPE_NONE_NV
                            ? g.triangles.vertex_count / 3
                            : g.triangles.index_count / 3;
    s.driver_object = dst.driver_object;
    s.driver_build_scratch = dst.driver_build_scratch;
    s.engine_object = need.object;
    s.engine_build_scratch = need.build_scratch;
    s.engine_bytes = record.ops[0].dst_size;
    c_.report.nv_sizes.push_back(s);
}

void NvReplay::build(const fbs::CmdBuildAccelerationStructureNV& b, const CommandRef& ref,
                     const ReplayLocation& where) {
    c_.lay_in_snapshots(b.inputs(), where);
    ++c_.report.counts.nv_builds;
    engine::NvBuildCommand cmd;
    resolve_inputs(c_, b, cmd, where);
    Object* dst = bind_build_structures(b, cmd, where);
    // The scratch rule is about the capturing driver's requirement when the trace holds it.
    const uint64_t driver_scratch =
        dst ? (cmd.update ? dst->driver_update_scratch : dst->driver_build_scratch) : 0;
    const bool driver_sizes = driver_scratch != 0 && !c_.report.engine_trace;
    const uint64_t available = cmd.scratch_available;
    if (driver_sizes) cmd.scratch_available = kWholeSize;
    engine::NvBuildOptions options;
    options.limits = limits_;
    options.max_findings_per_rule = c_.options.max_findings_per_rule;
    options.resolve_reference = [this](uint64_t h) { return resolve(h, false); };
    const auto started = std::chrono::steady_clock::now();
    engine::ExecutionRecord record = engine::execute_nv_build(cmd, c_.memory.image(), options);
    const uint64_t engine_ns = uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                            std::chrono::steady_clock::now() - started)
                                            .count());
    if (driver_sizes) apply_driver_scratch(record, cmd, available, driver_scratch);
    engine_findings(record, where);
    feed(ref, record, where);
    if (dst && record.ops[0].executed) {
        dst->built = true;
        dst->opaque = false;
        dst->built_flags = cmd.info.flags;
    }
    if (dst) note_sizes(*dst, cmd, record, where);
    if (c_.observe) c_.observe(std::move(record), engine_ns);
}

void NvReplay::deserialize(const fbs::CmdCopyMemoryToAccelerationStructure& copy,
                           const CommandRef& ref, const ReplayLocation& where) {
    c_.lay_in_snapshots(copy.inputs(), where);
    ++c_.report.counts.deserializations;
    if (khr_acceleration_structure_missing_)
        c_.add_finding({engine::kVuidDeserializeFeature,
                        "the device's enabled extensions (recorded in the trace) do not include "
                        "VK_KHR_acceleration_structure, "
                        "so its accelerationStructure feature cannot be enabled",
                        FindingSource::kEngine, where, -1, 0});
    engine::NvDeserializeCommand cmd;
    cmd.src_address = copy.src_address();
    cmd.mode = copy.mode();
    Object* dst = object(copy.dst());
    if (!dst) {
        c_.add_finding({kRuleUnknownObject,
                        "pInfo->dst " + hex(copy.dst()) + " was never created in the trace",
                        FindingSource::kReplay, where, -1, 0});
        cmd.dst.handle = copy.dst();
    } else {
        // A serialized object larger than the engine's requirement for dst's creation info
        // still deserializes (dst-03746 is about the size dst was created with).
        uint64_t deserialized = 0;
        if (const engine::MemoryRegion* r = c_.memory.image().find_region(cmd.src_address);
            r && cmd.src_address + 40 <= r->base + r->size) {
            engine::SerializedHeader h{};
            try {
                h = c_.memory.image().read<engine::SerializedHeader>(cmd.src_address,
                                                                     {"pInfo->src.deviceAddress",
                                                                      -1});
                deserialized = h.deserialized_size;
            } catch (const engine::MemoryFault&) {}
        }
        // Grow the shadow only up to the size dst was created with: a larger deserializedSize
        // breaks dst-03746 and must not allocate what a hostile header asks for.
        const uint64_t created =
            std::max({dst->driver_object, dst->khr_size,
                      dst->created ? engine::nv_memory_requirements(*dst->created).object : 0});
        if (dst->bound) ensure_shadow(*dst, where, deserialized <= created ? deserialized : 0);
        cmd.dst = binding(*dst, where);
    }
    engine::NvDeserializeOptions options;
    options.resolve_handle = [this](uint64_t h) { return resolve(h, false); };
    const auto started = std::chrono::steady_clock::now();
    engine::NvDeserializeResult r = engine::execute_nv_deserialize(cmd, c_.memory.image(), options);
    const uint64_t engine_ns = uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                            std::chrono::steady_clock::now() - started)
                                            .count());
    if (r.opaque && dst) {
        const uint64_t created = dst->driver_object ? dst->driver_object : dst->khr_size;
        if (created && r.header.deserialized_size > created)
            r.record.findings.push_back(
                engine::Finding{engine::kVuidDeserializeDstSize,
                                "deserializedSize " + std::to_string(r.header.deserialized_size) +
                                    " is above the " + std::to_string(created) + " bytes dst " +
                                    hex(dst->handle) + " was created with",
                                -1, 0});
        for (uint64_t h : r.handles)
            if (h != 0 && !by_driver_handle_.count(h))
                r.record.findings.push_back(engine::Finding{
                    engine::kRuleDeserializeHandleUnknown,
                    "handle " + hex(h) +
                        " of the serialized data names no acceleration structure created "
                        "before the deserialization",
                    -1, cmd.src_address});
        dst->opaque = true;
        dst->built = false;
        c_.add_finding(
            {kRuleOpaqueObject,
             "dst " + hex(dst->handle) +
                 " now holds another driver's object the engine cannot decode: builds and ray "
                 "checks that read it are not replayed",
             FindingSource::kReplay, where, -1, 0});
    }
    engine_findings(r.record, where);
    if (dst && r.record.ops[0].executed) {
        dst->built = true;
        dst->opaque = false;
        dst->built_flags = dst->created ? dst->created->flags : 0;
    }
    // The sync model: source read and destination written by one copy (in-use destinations).
    if (c_.options.check_hazards && r.record.accesses.size() == 2) {
        const engine::MemoryAccess& s = r.record.accesses[0];
        std::optional<AddressRange> d = dst ? c_.memory.object_range(dst->handle) : std::nullopt;
        Access src_access{{s.begin, s.end}, s.stage, s.access, false, "pInfo->src.deviceAddress"};
        if (d) {
            c_.report.counts.accesses += 2;
            c_.sync.record_deserialize(ref, src_access,
                                       Access{*d, r.record.accesses[1].stage,
                                              r.record.accesses[1].access, true, "pInfo->dst"});
        } else {
            ++c_.report.counts.accesses;
            c_.sync.record_access(ref, src_access);
        }
    }
    if (c_.observe) c_.observe(std::move(r.record), engine_ns);
}

void NvReplay::ray_check(const fbs::RayQueryCheck& check) {
    RayCheckResult out;
    out.label = check.label() ? check.label()->str() : "";
    out.acceleration_structure = check.acceleration_structure();
    out.after_submission = check.after_submission();
    ReplayLocation where{};
    where.submission = uint32_t(check.after_submission());
    where.name = "RayQueryCheck";
    auto fail = [&](std::string why) {
        out.why_not = std::move(why);
        c_.report.ray_checks.push_back(out);
    };
    Object* o = object(check.acceleration_structure());
    if (!o) {
        // The check may name the object by its device handle only.
        auto it = by_driver_handle_.find(check.device_handle());
        if (it != by_driver_handle_.end()) o = object(it->second);
    }
    if (!o) return fail("the acceleration structure was never created in the trace");
    if (o->opaque)
        return fail(
            "it holds another driver's deserialized object, which the engine cannot decode");
    if (!o->built || !o->shadow)
        return fail("the replay never built it (see the findings of its build)");
    std::vector<engine::Finding> findings;
    std::string error;
    auto scene = engine::NvScene::open(c_.memory.image(), o->shadow, &findings, &error);
    if (!scene) return fail("the rebuilt object does not open: " + error);
    for (const engine::Finding& f : findings)
        c_.add_finding({f.rule, f.message, FindingSource::kReplay, where, -1, f.address});
    const auto* rays = check.rays();
    const auto* results = check.results();
    const size_t n = std::min<size_t>(rays ? rays->size() : 0, results ? results->size() : 0);
    if (rays && results && rays->size() != results->size())
        c_.add_finding({kRuleRayDisagrees,
                        "ray check '" + out.label + "' holds " + std::to_string(rays->size()) +
                            " rays but " + std::to_string(results->size()) +
                            " results: only the first " + std::to_string(n) + " compared",
                        FindingSource::kReplay, where, -1, 0});
    out.checked = true;
    const engine::TraversalMode mode = c_.options.ray_check_traversal == RayCheckTraversal::kDouble
                                           ? engine::TraversalMode::kDouble
                                           : engine::TraversalMode::kFloat32;
    out.traversal = engine::traversal_mode_name(mode);
    size_t reported = 0;
    // Labels say how the rays were traced and can be long: the first words name the check.
    const std::string short_label =
        out.label.size() > 40 ? std::string(traces::utf8_prefix(out.label, 37)) + "..." : out.label;
    for (size_t i = 0; i < n; ++i) {
        const fbs::TracedRay* r = rays->Get(flatbuffers::uoffset_t(i));
        const fbs::RayHitResult* d = results->Get(flatbuffers::uoffset_t(i));
        const engine::Ray ray{{r->origin_x(), r->origin_y(), r->origin_z()},
                              r->t_min(),
                              {r->dir_x(), r->dir_y(), r->dir_z()},
                              r->t_max()};
        const engine::NvHit e = scene->closest(ray, r->ray_flags(), r->cull_mask(), mode);
        ++out.rays;
        const char* verdict = compare_answers(e, *d, out);
        if (!verdict) continue;
        ++out.disagree;
        const DisagreementCause cause = disagreement_cause(ray, e, *d);
        ++(cause == DisagreementCause::kFarTiny      ? out.disagree_far_tiny
           : cause == DisagreementCause::kDegenerate ? out.disagree_degenerate
                                                     : out.disagree_unexplained);
        if (reported++ >= c_.options.max_findings_per_rule) continue;
        const std::string text =
            disagreement_message(i, short_label, ray, *r, *d, e, verdict, cause, out.traversal);
        c_.add_finding({kRuleRayDisagrees, text, FindingSource::kVerify, where, int64_t(i), 0});
    }
    c_.report.ray_checks.push_back(out);
}

}  // namespace clastrace::replay::detail
