// VTK XML unstructured grid (.vtu) reading, reference: "VTK File Formats",
// XML file formats, in the VTK User's Guide. Arrays may be ascii, binary
// (base64 inline) or appended (raw or base64); the binary ones carry a header
// of UInt32 or UInt64 sizes, in either byte order, and may be compressed with
// zlib (vtkZLibDataCompressor, VTK's and meshio's default). Only tetrahedra
// are kept, as by the legacy reader (VtkTetNodes); pieces are joined.

#include <tinyxml2.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <charconv>
#include <cstdint>
#include <limits>
#include <optional>
#include <type_traits>

#include "mesh/binary_values.h"
#include "mesh/error.h"
#include "mesh/mesh_io.h"
#include "mesh/xml_error.h"

namespace tetcosim {
namespace {

using tinyxml2::XMLElement;

// zlib's deflate never shrinks data by more than about 1032 to 1: a block
// that claims more is damaged, and must not make the reader allocate for it
constexpr long kMaxDeflateRatio = 1032;
// an attribute's count (points, cells, components) above this is damaged
constexpr long kMaxCount = 1L << 40;

// The value types of a DataArray's `type` attribute.
constexpr std::array<BinaryType, 10> kTypes = {{{"Int8", 1, ValueKind::kSigned},
                                                {"UInt8", 1, ValueKind::kUnsigned},
                                                {"Int16", 2, ValueKind::kSigned},
                                                {"UInt16", 2, ValueKind::kUnsigned},
                                                {"Int32", 4, ValueKind::kSigned},
                                                {"UInt32", 4, ValueKind::kUnsigned},
                                                {"Int64", 8, ValueKind::kSigned},
                                                {"UInt64", 8, ValueKind::kUnsigned},
                                                {"Float32", 4, ValueKind::kFloat},
                                                {"Float64", 8, ValueKind::kFloat}}};

// "<Name>" of an element, for messages (built by appends: g++ 12 warns
// falsely of overlapping copies in "<" + name + ">")
std::string Tag(const XMLElement* element) {
  std::string tag = "<";
  tag.append(element->Name()).append(">");
  return tag;
}

bool IsSpace(char c) {
  return c == ' ' || c == '\n' || c == '\r' || c == '\t';
}

// The value of a base64 character, or -1.
int Base64Value(char c) {
  if (c >= 'A' && c <= 'Z') return c - 'A';
  if (c >= 'a' && c <= 'z') return c - 'a' + 26;
  if (c >= '0' && c <= '9') return c - '0' + 52;
  if (c == '+') return 62;
  if (c == '/') return 63;
  return -1;
}

// The bytes of one array's binary data, taken in order: raw bytes, or base64
// text decoded as it is taken. The base64 is read four characters at a time,
// each group giving one to three bytes as its '=' padding says, so a header
// encoded apart from its data (as VTK writes them) reads as the same bytes as
// one encoded with it.
class ByteStream {
 public:
  ByteStream(std::string_view data, bool base64) : data_(data), base64_(base64) {}

  // At least as many bytes as remain.
  size_t MaxRemaining() const {
    const size_t left = data_.size() - pos_;
    return base64_ ? decoded_.size() - taken_ + left / 4 * 3 + 3 : left;
  }

  // The next `count` bytes; nullopt when the data ends before them. Throws
  // the message of `fail` for a character that is not base64.
  template <typename Fail>
  std::optional<std::string_view> Take(size_t count, Fail&& fail) {
    if (!base64_) {
      if (count > data_.size() - pos_) return std::nullopt;
      std::string_view bytes = data_.substr(pos_, count);
      pos_ += count;
      return bytes;
    }
    // (decoded bytes not yet taken stay at the front of decoded_)
    decoded_.erase(0, taken_);
    taken_ = 0;
    while (decoded_.size() < count) {
      int quad[4];
      int n = 0;
      while (n < 4 && pos_ < data_.size()) {
        const char c = data_[pos_++];
        if (IsSpace(c)) continue;
        if (c == '=') {
          quad[n++] = -2;
          continue;
        }
        quad[n] = Base64Value(c);
        if (quad[n] < 0) fail(std::string("holds '") + c + "', not a base64 character");
        ++n;
      }
      if (n < 4) return std::nullopt;
      // "xy==" gives one byte, "xyz=" two, "xyzw" three
      const int bytes = quad[2] == -2 ? 1 : quad[3] == -2 ? 2 : 3;
      if (quad[0] < 0 || quad[1] < 0 || (bytes == 1 && quad[3] != -2)) {
        fail("holds '=' padding inside a group of four base64 characters");
      }
      const std::uint32_t bits = static_cast<std::uint32_t>(quad[0]) << 18 |
                                 static_cast<std::uint32_t>(quad[1]) << 12 |
                                 static_cast<std::uint32_t>(std::max(quad[2], 0)) << 6 |
                                 static_cast<std::uint32_t>(std::max(quad[3], 0));
      decoded_.push_back(static_cast<char>(bits >> 16));
      if (bytes > 1) decoded_.push_back(static_cast<char>(bits >> 8 & 0xFF));
      if (bytes > 2) decoded_.push_back(static_cast<char>(bits & 0xFF));
    }
    taken_ = count;
    return std::string_view(decoded_).substr(0, count);
  }

 private:
  std::string_view data_;
  bool base64_;
  size_t pos_ = 0;
  std::string decoded_;
  size_t taken_ = 0;
};

// The values of one DataArray, as T (double for points, long for cells), and
// for an ascii array the lines of the values Marks asks for.
template <typename T>
struct Values {
  std::vector<T> values;
  std::vector<long> mark_lines;
};

// The values of an ascii array whose lines a read records (for the errors of
// later checks): every `stride`-th, or those listed in `at` (rising).
struct Marks {
  long stride = 0;
  const std::vector<long>* at = nullptr;
};

class VtuReader {
 public:
  VtuReader(const std::string& path, std::string_view content) : path_(path), content_(content) {}

  RawMesh Read() {
    RawMesh raw;
    raw.source = path_;
    const std::string xml = SplitAppendedData();
    if (document_.Parse(xml.data(), xml.size()) != tinyxml2::XML_SUCCESS) {
      ThrowAt(path_, document_.ErrorLineNum(),
              "not well-formed XML: " + DescribeXmlError(document_) +
                  (document_.ErrorLineNum() > 0
                       ? "; mend the file at that line, or write it again (ParaView, meshio)"
                       : "; give a VTK XML unstructured grid (a <VTKFile> element)"));
    }
    const XMLElement* root = document_.RootElement();
    if (!root || std::string_view(root->Name()) != "VTKFile") {
      ThrowAt(path_, root ? root->GetLineNum() : 0,
              "not a VTK XML file: the top-level element must be <VTKFile>");
    }
    ReadFileAttributes(root);
    const XMLElement* grid = root->FirstChildElement("UnstructuredGrid");
    if (!grid) Fail(root, "<VTKFile> holds no <UnstructuredGrid>");
    if (appended_begin_ != std::string_view::npos) {
      const XMLElement* appended = root->FirstChildElement("AppendedData");
      const char* encoding = appended ? appended->Attribute("encoding") : nullptr;
      const std::string_view value = encoding ? encoding : "";
      if (value != "raw" && value != "base64") {
        Fail(appended ? appended : root,
             "<AppendedData> needs encoding=\"raw\" or encoding=\"base64\", not '" +
                 std::string(value) + "'");
      }
      appended_base64_ = value == "base64";
    }
    std::vector<double> positions;
    std::vector<int> tets;
    long num_cells_before = 0;
    const XMLElement* piece = grid->FirstChildElement("Piece");
    if (!piece) Fail(grid, "<UnstructuredGrid> holds no <Piece>");
    for (; piece; piece = piece->NextSiblingElement("Piece")) {
      ReadPiece(piece, raw, positions, tets, num_cells_before);
    }
    raw.positions = Eigen::Map<const Positions>(positions.data(),
                                                static_cast<Eigen::Index>(positions.size() / 3), 3);
    raw.tets = Eigen::Map<const Tets>(tets.data(), static_cast<Eigen::Index>(tets.size() / 4), 4);
    if (num_linearized_ > 0) raw.warnings.push_back(LinearizedTetsWarning(num_linearized_));
    return raw;
  }

 private:
  [[noreturn]] void Fail(const XMLElement* element, const std::string& message) const {
    ThrowAt(path_, element ? element->GetLineNum() : 0, message);
  }

  // The file's XML without the appended data, which may be raw bytes (no XML
  // parser takes them); their place is kept in appended_begin_/_end_.
  std::string SplitAppendedData() {
    const size_t tag = content_.find("<AppendedData");
    if (tag == std::string_view::npos) return std::string(content_);
    const long line = 1 + std::count(content_.begin(), content_.begin() + tag, '\n');
    const size_t tag_end = content_.find('>', tag);
    size_t underscore = tag_end == std::string_view::npos ? tag_end : tag_end + 1;
    while (underscore < content_.size() && IsSpace(content_[underscore])) ++underscore;
    const size_t close = content_.rfind("</AppendedData>");
    if (underscore >= content_.size() || content_[underscore] != '_' ||
        close == std::string_view::npos || close < underscore) {
      ThrowAt(path_, line,
              "<AppendedData> must hold '_' and then the data, and end with </AppendedData>; "
              "the file is cut short or damaged: write it again");
    }
    appended_begin_ = underscore + 1;
    appended_end_ = close;
    std::string xml(content_.substr(0, underscore));
    xml.append(content_.substr(close));
    return xml;
  }

  void ReadFileAttributes(const XMLElement* root) {
    const char* type = root->Attribute("type");
    if (!type || std::string_view(type) != "UnstructuredGrid") {
      Fail(root, "a VTK XML file of type '" + std::string(type ? type : "") +
                     "' holds no tetrahedra; tetcosim reads type=\"UnstructuredGrid\" (.vtu)");
    }
    if (const char* order = root->Attribute("byte_order")) {
      const std::string_view value = order;
      if (value != "LittleEndian" && value != "BigEndian") {
        Fail(root,
             "byte_order must be LittleEndian or BigEndian, not '" + std::string(value) + "'");
      }
      big_endian_ = value == "BigEndian";
    }
    if (const char* header = root->Attribute("header_type")) {
      const std::string_view value = header;
      if (value != "UInt32" && value != "UInt64") {
        Fail(root, "header_type must be UInt32 or UInt64, not '" + std::string(value) + "'");
      }
      header_size_ = value == "UInt64" ? 8 : 4;
    }
    if (const char* compressor = root->Attribute("compressor")) {
      const std::string_view value = compressor;
      if (value == "vtkZLibDataCompressor") {
        zlib_ = true;
      } else if (!value.empty()) {
        Fail(root, "compressor '" + std::string(value) +
                       "' is not supported; tetcosim reads vtkZLibDataCompressor or no "
                       "compression: save the file again with one of those (ParaView: Save Data, "
                       "Compressor Type ZLib or None)");
      }
    }
  }

  long Count(const XMLElement* element, const char* attribute, long fallback = -1) const {
    const char* text = element->Attribute(attribute);
    if (!text) {
      if (fallback >= 0) return fallback;
      Fail(element, Tag(element) + " needs the attribute " + attribute);
    }
    const std::string_view value = text;
    long count = -1;
    auto [end, ec] = std::from_chars(value.data(), value.data() + value.size(), count);
    while (end < value.data() + value.size() && IsSpace(*end)) ++end;  // (VTK pads them)
    if (ec != std::errc() || end != value.data() + value.size() || count < 0 || count > kMaxCount) {
      Fail(element, std::string(attribute) + "=\"" + std::string(value.substr(0, 40)) +
                        "\" is not a count (a whole number from 0 to " + std::to_string(kMaxCount) +
                        ")");
    }
    return count;
  }

  // The DataArray child of `parent` named `name` (nullptr: the first).
  const XMLElement* FindArray(const XMLElement* parent, const char* name) const {
    for (const XMLElement* array = parent->FirstChildElement("DataArray"); array;
         array = array->NextSiblingElement("DataArray")) {
      const char* array_name = array->Attribute("Name");
      if (!name || (array_name && std::string_view(array_name) == name)) return array;
    }
    std::string message = Tag(parent) + " has no DataArray";
    if (name) message.append(" named '").append(name).append("'");
    Fail(parent, message);
  }

  std::string ArrayName(const XMLElement* array) const {
    const char* name = array->Attribute("Name");
    return "DataArray '" + std::string(name ? name : "") + "'";
  }

  // The values of DataArray `array`: `count` tuples of `components` values.
  // The lines of the values `marks` lists (ascii only).
  template <typename T>
  Values<T> ReadArray(const XMLElement* array, long count, int components, Marks marks = {}) {
    const char* type_text = array->Attribute("type");
    const BinaryType* type = type_text ? FindBinaryType(kTypes, type_text) : nullptr;
    if (!type) {
      Fail(array, ArrayName(array) + " has type '" + std::string(type_text ? type_text : "") +
                      "'; expected one of Int8, UInt8, Int16, UInt16, Int32, UInt32, Int64, "
                      "UInt64, Float32, Float64");
    }
    if constexpr (std::is_integral_v<T>) {
      if (type->kind == ValueKind::kFloat) {
        Fail(array, ArrayName(array) + " holds " + std::string(type->name) +
                        " values; cell indices, offsets and types are whole numbers (an Int type)");
      }
    }
    const long file_components = Count(array, "NumberOfComponents", 1);
    if (file_components != components) {
      Fail(array, ArrayName(array) + " has " + std::to_string(file_components) +
                      " components; expected " + std::to_string(components));
    }
    const long num_values = count * components;
    const char* format_text = array->Attribute("format");
    const std::string_view format = format_text ? format_text : "ascii";
    if (format == "ascii") return ReadAscii<T>(array, num_values, marks);
    if (format != "binary" && format != "appended") {
      Fail(array, ArrayName(array) + " has format '" + std::string(format) +
                      "'; expected ascii, binary or appended");
    }
    std::string bytes;
    if (format == "binary") {
      const char* text = array->GetText();
      ByteStream stream(text ? text : "", /*base64=*/true);
      bytes = ReadBinary(array, stream, num_values, type->size);
    } else {
      if (appended_begin_ == std::string_view::npos) {
        Fail(array, ArrayName(array) + " is appended, but the file has no <AppendedData>");
      }
      const long offset = Count(array, "offset");
      const std::string_view data =
          content_.substr(appended_begin_, appended_end_ - appended_begin_);
      if (offset > static_cast<long>(data.size())) {
        Fail(array, ArrayName(array) + " has offset " + std::to_string(offset) + ", beyond the " +
                        std::to_string(data.size()) +
                        " bytes of <AppendedData>; the file is cut short or damaged");
      }
      ByteStream stream(data.substr(static_cast<size_t>(offset)), appended_base64_);
      bytes = ReadBinary(array, stream, num_values, type->size);
    }
    Values<T> result;
    result.values.resize(static_cast<size_t>(num_values));
    for (size_t i = 0; i < result.values.size(); ++i) {
      const std::uint64_t bits =
          BytesToBits(bytes.data() + i * static_cast<size_t>(type->size), type->size, big_endian_);
      if constexpr (std::is_integral_v<T>) {
        result.values[i] = BitsToLong(bits, type->size, type->kind);
      } else {
        result.values[i] = BitsToDouble(bits, type->size, type->kind);
      }
    }
    return result;
  }

  template <typename T>
  Values<T> ReadAscii(const XMLElement* array, long num_values, Marks marks) {
    const char* raw_text = array->GetText();
    const std::string_view text = raw_text ? raw_text : "";
    // (each value takes a character and a separator: a count beyond that is
    // not in the file, and is not allocated for)
    if (num_values > static_cast<long>(text.size() / 2 + 1)) {
      Fail(array, ArrayName(array) + " holds " + std::to_string(text.size()) +
                      " characters, too few for the " + std::to_string(num_values) +
                      " values its piece needs; the file is cut short or damaged");
    }
    Values<T> result;
    result.values.reserve(static_cast<size_t>(num_values));
    long line = array->GetLineNum();
    size_t pos = 0;
    size_t next_mark = 0;
    for (long i = 0;; ++i) {
      while (pos < text.size() && IsSpace(text[pos])) line += text[pos++] == '\n';
      if (pos == text.size()) {
        if (i == num_values) break;
        ThrowAt(path_, line,
                ArrayName(array) + " holds " + std::to_string(i) + " values; its piece needs " +
                    std::to_string(num_values));
      }
      size_t end = pos;
      while (end < text.size() && !IsSpace(text[end])) ++end;
      const std::string_view token = text.substr(pos, end - pos);
      if (i == num_values) {
        ThrowAt(path_, line,
                ArrayName(array) + " holds more than the " + std::to_string(num_values) +
                    " values its piece needs (found '" + std::string(token.substr(0, 40)) + "')");
      }
      T value{};
      auto [stop, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
      if (ec != std::errc() || stop != token.data() + token.size()) {
        ThrowAt(path_, line,
                ArrayName(array) + ": '" + std::string(token.substr(0, 40)) + "' is not " +
                    (std::is_integral_v<T> ? "a whole number" : "a number"));
      }
      if (marks.stride > 0 && i % marks.stride == 0) result.mark_lines.push_back(line);
      for (; marks.at && next_mark < marks.at->size() && (*marks.at)[next_mark] == i; ++next_mark) {
        result.mark_lines.push_back(line);
      }
      result.values.push_back(value);
      pos = end;
    }
    // (marks past the last value: cells of no points at the end)
    if (marks.at) result.mark_lines.resize(marks.at->size(), line);
    return result;
  }

  // The bytes of `num_values` values of `size` bytes each from `stream`:
  // header and data, uncompressed or zlib blocks.
  std::string ReadBinary(const XMLElement* array, ByteStream& stream, long num_values, int size) {
    auto fail = [&](const std::string& message) -> void {
      Fail(array, ArrayName(array) + "'s binary data " + message + "; the file is damaged");
    };
    auto take = [&](size_t count, const char* what) {
      std::optional<std::string_view> bytes = stream.Take(count, fail);
      if (!bytes) {
        Fail(array, ArrayName(array) + "'s binary data ends before its " + what +
                        "; the file is cut short or damaged");
      }
      return *bytes;
    };
    auto header_value = [&](const char* what) {
      return BytesToBits(take(static_cast<size_t>(header_size_), what).data(), header_size_,
                         big_endian_);
    };
    const std::uint64_t expected =
        static_cast<std::uint64_t>(num_values) * static_cast<std::uint64_t>(size);
    auto check_total = [&](std::uint64_t total) {
      if (total != expected) {
        Fail(array, ArrayName(array) + " holds " + std::to_string(total) +
                        " bytes; its piece needs " + std::to_string(num_values) + " values of " +
                        std::to_string(size) + " bytes (" + std::to_string(expected) + ")");
      }
    };
    if (!zlib_) {
      check_total(header_value("size header"));
      return std::string(take(static_cast<size_t>(expected), "values"));
    }
    // header: blocks, block size, last block's size, each block's compressed size
    const std::uint64_t num_blocks = header_value("block count");
    const std::uint64_t block_size = header_value("block size");
    std::uint64_t last_size = header_value("last block size");
    if (num_blocks > 0 && last_size == 0) last_size = block_size;  // (a full last block)
    if (num_blocks > expected ||
        num_blocks > stream.MaxRemaining() / static_cast<size_t>(header_size_) ||
        (num_blocks > 0 && (block_size == 0 || last_size > block_size))) {
      Fail(array, ArrayName(array) + " has a compression header of " + std::to_string(num_blocks) +
                      " blocks of " + std::to_string(block_size) + " bytes (the last " +
                      std::to_string(last_size) + "), not possible for " +
                      std::to_string(expected) + " bytes; the file is damaged");
    }
    check_total(num_blocks == 0 ? 0 : (num_blocks - 1) * block_size + last_size);
    std::vector<std::uint64_t> compressed(static_cast<size_t>(num_blocks));
    for (std::uint64_t& bytes : compressed) bytes = header_value("compressed block sizes");
    std::string out;  // (grown block by block: each block's size is checked first)
    for (std::uint64_t b = 0; b < num_blocks; ++b) {
      const std::uint64_t unpacked = b + 1 == num_blocks ? last_size : block_size;
      const std::uint64_t packed = compressed[static_cast<size_t>(b)];
      if (packed > std::numeric_limits<uLong>::max() / 2 ||
          unpacked > static_cast<std::uint64_t>(kMaxDeflateRatio) * packed + 64) {
        Fail(array, ArrayName(array) + "'s compressed block " + std::to_string(b) + " claims " +
                        std::to_string(packed) + " bytes that unpack to " +
                        std::to_string(unpacked) + "; the file is damaged");
      }
      const std::string_view source = take(static_cast<size_t>(packed), "compressed blocks");
      const size_t at = out.size();
      out.resize(at + static_cast<size_t>(unpacked));
      uLongf length = static_cast<uLongf>(unpacked);
      const int status =
          uncompress(reinterpret_cast<Bytef*>(out.data() + at), &length,
                     reinterpret_cast<const Bytef*>(source.data()), static_cast<uLong>(packed));
      if (status != Z_OK || length != unpacked) {
        Fail(array, ArrayName(array) + "'s compressed block " + std::to_string(b) +
                        " does not unpack to its " + std::to_string(unpacked) + " bytes (zlib: " +
                        (status == Z_OK ? "too short" : zError(status)) + "); the file is damaged");
      }
    }
    return out;
  }

  void ReadPiece(const XMLElement* piece, RawMesh& raw, std::vector<double>& positions,
                 std::vector<int>& tets, long& num_cells_before) {
    const long num_points = Count(piece, "NumberOfPoints");
    const long num_cells = Count(piece, "NumberOfCells");
    const long first_point = static_cast<long>(positions.size() / 3);
    if (num_points > TetMesh::kMaxVertices - first_point) {
      Fail(piece, "the mesh has more than " + std::to_string(TetMesh::kMaxVertices) +
                      " points, the most one mesh may hold (32-bit indices); split it");
    }
    const XMLElement* points = piece->FirstChildElement("Points");
    const bool has_array = points && points->FirstChildElement("DataArray");
    if (num_points == 0 && num_cells == 0 && !has_array) return;  // (an empty piece)
    if (!points) Fail(piece, "<Piece> has no <Points>");
    const XMLElement* points_array = FindArray(points, nullptr);
    Values<double> coordinates = ReadArray<double>(points_array, num_points, 3, {.stride = 3});
    positions.insert(positions.end(), coordinates.values.begin(), coordinates.values.end());
    for (long v = 0; v < num_points; ++v) {
      raw.node_lines.push_back(coordinates.mark_lines.empty()
                                   ? points_array->GetLineNum()
                                   : coordinates.mark_lines[static_cast<size_t>(v)]);
    }
    const XMLElement* cells = piece->FirstChildElement("Cells");
    if (!cells) {
      if (num_cells == 0) return;
      Fail(piece, "<Piece> has " + std::to_string(num_cells) + " cells but no <Cells>");
    }
    const XMLElement* offsets_array = FindArray(cells, "offsets");
    const std::vector<long> offsets = ReadArray<long>(offsets_array, num_cells, 1).values;
    const std::vector<long> types = ReadArray<long>(FindArray(cells, "types"), num_cells, 1).values;
    // offsets: where each cell's indices end, rising to the connectivity's size
    long previous = 0;
    for (long c = 0; c < num_cells; ++c) {
      const long offset = offsets[static_cast<size_t>(c)];
      if (offset < previous) {
        Fail(offsets_array, "DataArray 'offsets' value " + std::to_string(c) + " (" +
                                std::to_string(offset) + ") is below the one before it (" +
                                std::to_string(previous) +
                                "); offsets must rise, each by a cell's point count");
      }
      previous = offset;
    }
    const XMLElement* connectivity_array = FindArray(cells, "connectivity");
    const long num_indices = num_cells == 0 ? 0 : offsets.back();
    // (an ascii connectivity's line of each cell: the line of its first index)
    std::vector<long> starts(static_cast<size_t>(num_cells));
    for (long c = 1; c < num_cells; ++c) {
      starts[static_cast<size_t>(c)] = offsets[static_cast<size_t>(c) - 1];
    }
    const Values<long> connectivity =
        ReadArray<long>(connectivity_array, num_indices, 1, {.at = &starts});
    for (long c = 0; c < num_cells; ++c) {
      const long begin = starts[static_cast<size_t>(c)];
      const long end = offsets[static_cast<size_t>(c)];
      const long line = connectivity.mark_lines.empty()
                            ? connectivity_array->GetLineNum()
                            : connectivity.mark_lines[static_cast<size_t>(c)];
      const long type = types[static_cast<size_t>(c)];
      const int nodes = VtkTetNodes(type);
      if (nodes == 0) continue;
      const long cell = num_cells_before + c;
      if (end - begin != nodes) {
        ThrowAt(path_, line,
                "cell " + std::to_string(cell) + " has type " + std::to_string(type) +
                    " (a tetrahedron of " + std::to_string(nodes) + " points) but " +
                    std::to_string(end - begin) + " points");
      }
      num_linearized_ += nodes != 4;
      for (long k = begin; k < begin + 4; ++k) {
        const long v = connectivity.values[static_cast<size_t>(k)];
        if (v < 0 || v >= num_points) {
          ThrowAt(path_, line,
                  "cell " + std::to_string(cell) + " refers to point " + std::to_string(v) +
                      ", outside its piece's " + std::to_string(num_points) + " points");
        }
        tets.push_back(static_cast<int>(first_point + v));
      }
      raw.element_ids.push_back(cell);
      raw.element_lines.push_back(line);
      if (static_cast<long>(raw.element_ids.size()) > TetMesh::kMaxTets) {
        Fail(piece, "the mesh has more than " + std::to_string(TetMesh::kMaxTets) +
                        " tetrahedra, the most one mesh may hold (32-bit indices); split it");
      }
    }
    num_cells_before += num_cells;
  }

  std::string path_;
  std::string_view content_;
  tinyxml2::XMLDocument document_;
  size_t appended_begin_ = std::string_view::npos;
  size_t appended_end_ = std::string_view::npos;
  bool appended_base64_ = false;
  bool big_endian_ = false;
  int header_size_ = 4;  // UInt32, VTK's default before header_type existed
  bool zlib_ = false;
  long num_linearized_ = 0;  // quadratic tetrahedra, read from their corners
};

}  // namespace

RawMesh ReadVtu(const std::string& path, std::string_view content) {
  return VtuReader(path, content).Read();
}

}  // namespace tetcosim
