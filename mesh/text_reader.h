#pragma once

// A scanner over a whole file held in memory, shared by the readers: text
// tokens with line numbers, binary values with bounds checks, and errors that
// say where they happened ("file:line: ..." in text, "file: byte N: ..." in
// binary sections). Reading past the end is a clear error, never undefined
// behaviour.

#include <cstddef>
#include <cstring>
#include <string>
#include <string_view>

namespace tetcosim {

// The whole content of a file. Throws Error when it cannot be opened or read.
std::string ReadFileContents(const std::string& path);

class Scanner {
 public:
  // comment: a character that starts a comment running to the end of the line
  // ('\0' for none).
  Scanner(std::string source, std::string_view text, char comment = '\0');

  const std::string& source() const { return source_; }
  long line() const { return line_; }
  size_t offset() const { return pos_; }
  bool AtEnd();  // true when only white space (and comments) remain

  // The next white-space separated token; Fail()s at the end of the file with
  // "expected <what>".
  std::string_view Token(std::string_view what);
  // The next token if it is on the current line, else an empty view (the
  // position is left at the line end).
  std::string_view TokenOnLine();
  // The next token, left to be read again (Token's errors at the end).
  std::string_view PeekToken(std::string_view what);
  long Int(std::string_view what);
  double Double(std::string_view what);
  // Reads a token and Fail()s unless it equals expected.
  void Expect(std::string_view expected);
  // Moves past the rest of the current line (including its newline).
  void SkipLine();
  // Moves to just after the next line that is exactly `marker` (for skipping
  // unknown sections, text or binary); Fail()s if there is none.
  void SkipPast(std::string_view marker);

  // Raw bytes: the binary sections of Gmsh files.
  template <typename T>
  T Binary(std::string_view what) {
    T value;
    RequireBytes(sizeof(T), what);
    std::memcpy(&value, text_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return value;
  }
  void RequireBytes(size_t count, std::string_view what);
  // Moves past `count` bytes (binary data not needed); Fail()s past the end.
  void SkipBytes(size_t count) {
    RequireBytes(count, "binary data");
    pos_ += count;
  }
  // Fail()s unless `count` items of at least `bytes_each` bytes can still
  // follow: a header that claims more than the file holds is truncated or
  // corrupt, and must not make the reader allocate for it.
  void CheckCount(long count, size_t bytes_each, std::string_view what);
  void set_binary(bool binary) { binary_ = binary; }

  [[noreturn]] void Fail(const std::string& message) const;

 private:
  void SkipSpace();

  std::string source_;
  std::string_view text_;
  char comment_;
  size_t pos_ = 0;
  long line_ = 1;
  bool binary_ = false;
};

}  // namespace tetcosim
