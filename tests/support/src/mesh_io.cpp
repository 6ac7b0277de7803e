// SPDX-License-Identifier: Apache-2.0
// Minimal OBJ and PLY readers: positions and faces only, every malformed input a MeshLoadError
// that names the file and the line or byte offset.
#include "clastrace/testsupport/mesh.h"

#include <cctype>
#include <charconv>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>

namespace clastrace::testsupport {
namespace {

std::string read_file(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw MeshLoadError(path.string() + ": cannot open");
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

[[noreturn]] void fail(const std::filesystem::path& path, const std::string& where,
                       const std::string& what) {
    throw MeshLoadError(path.string() + ":" + where + ": " + what);
}

bool parse_float(std::string_view token, float& out) {
    // strtof accepts the "1e-5", "inf" and "-0" spellings found in real OBJ files.
    std::string s(token);
    char* end = nullptr;
    out = std::strtof(s.c_str(), &end);
    return end != s.c_str() && *end == '\0';
}

std::vector<std::string_view> split_ws(std::string_view line) {
    std::vector<std::string_view> out;
    size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == '\r')) ++i;
        size_t j = i;
        while (j < line.size() && !(line[j] == ' ' || line[j] == '\t' || line[j] == '\r')) ++j;
        if (j > i) out.push_back(line.substr(i, j - i));
        i = j;
    }
    return out;
}

}  // namespace

TriangleMesh load_obj(const std::filesystem::path& path) {
    const std::string text = read_file(path);
    TriangleMesh mesh;
    mesh.name = path.filename().string();
    size_t line_no = 0, pos = 0;
    while (pos < text.size()) {
        size_t end = text.find('\n', pos);
        if (end == std::string::npos) end = text.size();
        std::string_view line(text.data() + pos, end - pos);
        pos = end + 1;
        ++line_no;
        auto tok = split_ws(line);
        if (tok.empty()) continue;
        const std::string where = std::to_string(line_no);
        if (tok[0] == "v") {
            if (tok.size() < 4) fail(path, where, "vertex needs 3 coordinates");
            Float3 p{};
            for (int k = 0; k < 3; ++k)
                if (!parse_float(tok[1 + k], p[k]))
                    fail(path, where, "bad coordinate '" + std::string(tok[1 + k]) + "'");
            mesh.positions.push_back(p);
        } else if (tok[0] == "f") {
            if (tok.size() < 4) fail(path, where, "face needs at least 3 vertices");
            std::vector<uint32_t> face;
            for (size_t k = 1; k < tok.size(); ++k) {
                std::string_view ref =
                    tok[k].substr(0, tok[k].find('/'));  // "v/vt/vn": position only
                long long idx = 0;
                auto [p, ec] = std::from_chars(ref.data(), ref.data() + ref.size(), idx);
                if (ec != std::errc() || p != ref.data() + ref.size() || idx == 0)
                    fail(path, where, "bad face index '" + std::string(tok[k]) + "'");
                const long long n = static_cast<long long>(mesh.positions.size());
                const long long resolved = idx > 0 ? idx - 1 : n + idx;
                if (resolved < 0 || resolved >= n)
                    fail(path, where,
                         "face index " + std::to_string(idx) + " out of range (" +
                             std::to_string(n) + " vertices so far)");
                face.push_back(static_cast<uint32_t>(resolved));
            }
            for (size_t k = 1; k + 1 < face.size(); ++k)
                mesh.triangles.push_back({face[0], face[k], face[k + 1]});
        }
    }
    return mesh;
}

namespace {

enum class PlyType { i8, u8, i16, u16, i32, u32, f32, f64 };

bool ply_type(std::string_view s, PlyType& t) {
    static const std::pair<const char*, PlyType> names[] = {
        {"char", PlyType::i8},    {"int8", PlyType::i8},     {"uchar", PlyType::u8},
        {"uint8", PlyType::u8},   {"short", PlyType::i16},   {"int16", PlyType::i16},
        {"ushort", PlyType::u16}, {"uint16", PlyType::u16},  {"int", PlyType::i32},
        {"int32", PlyType::i32},  {"uint", PlyType::u32},    {"uint32", PlyType::u32},
        {"float", PlyType::f32},  {"float32", PlyType::f32}, {"double", PlyType::f64},
        {"float64", PlyType::f64}};
    for (auto& [n, v] : names)
        if (s == n) {
            t = v;
            return true;
        }
    return false;
}

size_t ply_size(PlyType t) {
    switch (t) {
    case PlyType::i8:
    case PlyType::u8: return 1;
    case PlyType::i16:
    case PlyType::u16: return 2;
    case PlyType::i32:
    case PlyType::u32:
    case PlyType::f32: return 4;
    case PlyType::f64: return 8;
    }
    return 0;
}

struct PlyProperty {
    std::string name;
    bool is_list = false;
    PlyType count_type{}, type{};
};
struct PlyElement {
    std::string name;
    uint64_t count = 0;
    std::vector<PlyProperty> properties;
};

// Reads one value, ascii or binary, as double (exact for every PLY integer and float type).
class PlyReader {
public:
    PlyReader(const std::filesystem::path& path, const std::string& data, size_t pos, bool binary)
        : path_(path), data_(data), pos_(pos), binary_(binary) {}

    double value(PlyType t) {
        if (binary_) {
            const size_t n = ply_size(t);
            if (pos_ + n > data_.size())
                fail(path_, "byte " + std::to_string(pos_), "file ends inside a binary value");
            const char* p = data_.data() + pos_;
            pos_ += n;
            switch (t) {
            case PlyType::i8: {
                int8_t v;
                std::memcpy(&v, p, 1);
                return v;
            }
            case PlyType::u8: {
                uint8_t v;
                std::memcpy(&v, p, 1);
                return v;
            }
            case PlyType::i16: {
                int16_t v;
                std::memcpy(&v, p, 2);
                return v;
            }
            case PlyType::u16: {
                uint16_t v;
                std::memcpy(&v, p, 2);
                return v;
            }
            case PlyType::i32: {
                int32_t v;
                std::memcpy(&v, p, 4);
                return v;
            }
            case PlyType::u32: {
                uint32_t v;
                std::memcpy(&v, p, 4);
                return v;
            }
            case PlyType::f32: {
                float v;
                std::memcpy(&v, p, 4);
                return v;
            }
            case PlyType::f64: {
                double v;
                std::memcpy(&v, p, 8);
                return v;
            }
            }
            return 0;
        }
        while (pos_ < data_.size() && std::isspace(static_cast<unsigned char>(data_[pos_]))) ++pos_;
        const size_t start = pos_;
        while (pos_ < data_.size() && !std::isspace(static_cast<unsigned char>(data_[pos_])))
            ++pos_;
        if (start == pos_)
            fail(path_, "byte " + std::to_string(start), "file ends inside the ascii body");
        std::string tok(data_.data() + start, pos_ - start);
        char* end = nullptr;
        const double v = std::strtod(tok.c_str(), &end);
        if (*end != '\0')
            fail(path_, "byte " + std::to_string(start), "bad ascii value '" + tok + "'");
        return v;
    }
    size_t offset() const { return pos_; }

private:
    const std::filesystem::path& path_;
    const std::string& data_;
    size_t pos_;
    bool binary_;
};

}  // namespace

TriangleMesh load_ply(const std::filesystem::path& path) {
    const std::string data = read_file(path);
    TriangleMesh mesh;
    mesh.name = path.filename().string();
    if (data.compare(0, 3, "ply") != 0) fail(path, "byte 0", "missing 'ply' magic");
    const size_t header_end = data.find("end_header");
    if (header_end == std::string::npos) fail(path, "header", "no end_header");
    size_t body = data.find('\n', header_end);
    if (body == std::string::npos) fail(path, "header", "nothing after end_header");
    ++body;

    std::vector<PlyElement> elements;
    bool binary = false;
    std::istringstream header(data.substr(0, header_end));
    std::string line;
    size_t line_no = 0;
    while (std::getline(header, line)) {
        ++line_no;
        auto tok = split_ws(line);
        const std::string where = "header line " + std::to_string(line_no);
        if (tok.empty() || tok[0] == "comment" || tok[0] == "obj_info" || tok[0] == "ply") continue;
        if (tok[0] == "format") {
            if (tok.size() < 2) fail(path, where, "format line incomplete");
            if (tok[1] == "ascii")
                binary = false;
            else if (tok[1] == "binary_little_endian")
                binary = true;
            else
                fail(path, where, "unsupported format '" + std::string(tok[1]) + "'");
        } else if (tok[0] == "element") {
            if (tok.size() < 3) fail(path, where, "element line incomplete");
            PlyElement e;
            e.name = std::string(tok[1]);
            auto [p, ec] = std::from_chars(tok[2].data(), tok[2].data() + tok[2].size(), e.count);
            if (ec != std::errc()) fail(path, where, "bad element count");
            elements.push_back(e);
        } else if (tok[0] == "property") {
            if (elements.empty()) fail(path, where, "property before any element");
            PlyProperty prop;
            if (tok.size() >= 5 && tok[1] == "list") {
                prop.is_list = true;
                if (!ply_type(tok[2], prop.count_type) || !ply_type(tok[3], prop.type))
                    fail(path, where, "bad list types");
                prop.name = std::string(tok[4]);
            } else if (tok.size() >= 3) {
                if (!ply_type(tok[1], prop.type))
                    fail(path, where, "bad property type '" + std::string(tok[1]) + "'");
                prop.name = std::string(tok[2]);
            } else {
                fail(path, where, "property line incomplete");
            }
            elements.back().properties.push_back(prop);
        }
    }

    // Hostile counts must not reserve memory the file cannot back: every value takes >= 1 byte.
    PlyReader reader(path, data, body, binary);
    for (const PlyElement& e : elements) {
        if (e.count > data.size())
            fail(path, "element " + e.name,
                 "count " + std::to_string(e.count) + " exceeds file size");
        const bool is_vertex = e.name == "vertex";
        const bool is_face = e.name == "face";
        int xyz[3] = {-1, -1, -1};
        for (size_t k = 0; k < e.properties.size(); ++k) {
            if (e.properties[k].name == "x") xyz[0] = int(k);
            if (e.properties[k].name == "y") xyz[1] = int(k);
            if (e.properties[k].name == "z") xyz[2] = int(k);
        }
        if (is_vertex && (xyz[0] < 0 || xyz[1] < 0 || xyz[2] < 0))
            fail(path, "element vertex", "needs x, y and z properties");
        for (uint64_t i = 0; i < e.count; ++i) {
            Float3 p{};
            for (size_t k = 0; k < e.properties.size(); ++k) {
                const PlyProperty& prop = e.properties[k];
                if (!prop.is_list) {
                    const double v = reader.value(prop.type);
                    for (int c = 0; c < 3; ++c)
                        if (int(k) == xyz[c]) p[c] = static_cast<float>(v);
                    continue;
                }
                const double count = reader.value(prop.count_type);
                if (count < 0 || count > 1e6)
                    fail(path, "byte " + std::to_string(reader.offset()), "bad list length");
                std::vector<uint32_t> face;
                for (int j = 0; j < int(count); ++j) {
                    const double v = reader.value(prop.type);
                    face.push_back(static_cast<uint32_t>(v < 0 ? UINT32_MAX : v));
                }
                if (is_face && (prop.name == "vertex_indices" || prop.name == "vertex_index")) {
                    for (size_t j = 1; j + 1 < face.size(); ++j)
                        mesh.triangles.push_back({face[0], face[j], face[j + 1]});
                }
            }
            if (is_vertex) mesh.positions.push_back(p);
        }
    }
    for (size_t t = 0; t < mesh.triangles.size(); ++t)
        for (uint32_t v : mesh.triangles[t])
            if (v >= mesh.positions.size())
                fail(path, "face " + std::to_string(t),
                     "vertex index " + std::to_string(v) + " out of range (" +
                         std::to_string(mesh.positions.size()) + " vertices)");
    return mesh;
}

TriangleMesh load_mesh(const std::filesystem::path& path) {
    const std::string ext = path.extension().string();
    if (ext == ".obj" || ext == ".OBJ") return load_obj(path);
    if (ext == ".ply" || ext == ".PLY") return load_ply(path);
    throw MeshLoadError(path.string() + ": unknown mesh extension '" + ext + "'");
}

void save_obj(const TriangleMesh& mesh, const std::filesystem::path& path) {
    std::ofstream out(path);
    out.precision(9);  // 9 significant digits round-trip every float exactly
    for (const Float3& p : mesh.positions)
        out << "v " << p[0] << ' ' << p[1] << ' ' << p[2] << '\n';
    for (const Triangle& t : mesh.triangles)
        out << "f " << t[0] + 1 << ' ' << t[1] + 1 << ' ' << t[2] + 1 << '\n';
    if (!out) throw MeshLoadError(path.string() + ": write failed");
}

void save_ply(const TriangleMesh& mesh, const std::filesystem::path& path, bool binary) {
    std::ofstream out(path, std::ios::binary);
    out << "ply\nformat " << (binary ? "binary_little_endian" : "ascii") << " 1.0\n"
        << "element vertex " << mesh.positions.size()
        << "\nproperty float x\nproperty float y\nproperty float z\n"
        << "element face " << mesh.triangles.size()
        << "\nproperty list uchar uint vertex_indices\nend_header\n";
    out.precision(9);
    for (const Float3& p : mesh.positions) {
        if (binary)
            out.write(reinterpret_cast<const char*>(p.data()), 12);
        else
            out << p[0] << ' ' << p[1] << ' ' << p[2] << '\n';
    }
    for (const Triangle& t : mesh.triangles) {
        if (binary) {
            const uint8_t n = 3;
            out.write(reinterpret_cast<const char*>(&n), 1);
            out.write(reinterpret_cast<const char*>(t.data()), 12);
        } else {
            out << "3 " << t[0] << ' ' << t[1] << ' ' << t[2] << '\n';
        }
    }
    if (!out) throw MeshLoadError(path.string() + ": write failed");
}

std::filesystem::path assimp_models_dir() { return "/usr/share/assimp/models"; }

}  // namespace clastrace::testsupport
