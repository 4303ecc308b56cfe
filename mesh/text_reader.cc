#include "mesh/text_reader.h"

#include <sys/stat.h>
#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>

#include "mesh/error.h"

namespace tetcosim {

std::string ReadFileContents(const std::string& path) {
  struct stat info {};
  if (stat(path.c_str(), &info) != 0) {
    ThrowAt(path, 0, std::string("cannot open: ") + std::strerror(errno) + "; check the path");
  }
  if (S_ISDIR(info.st_mode)) {
    ThrowAt(path, 0, "is a directory, not a mesh file");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    ThrowAt(path, 0, std::string("cannot open: ") + std::strerror(errno));
  }
  std::ostringstream content;
  content << in.rdbuf();
  if (in.bad()) {
    ThrowAt(path, 0, "read error");
  }
  return std::move(content).str();
}

Scanner::Scanner(std::string source, std::string_view text, char comment)
    : source_(std::move(source)), text_(text), comment_(comment) {}

void Scanner::Fail(const std::string& message) const {
  if (binary_) {
    ThrowAt(source_, 0, "byte " + std::to_string(pos_) + ": " + message);
  }
  ThrowAt(source_, line_, message);
}

void Scanner::SkipSpace() {
  while (pos_ < text_.size()) {
    char c = text_[pos_];
    if (c == '\n') {
      ++line_;
      ++pos_;
    } else if (c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v') {
      ++pos_;
    } else if (comment_ != '\0' && c == comment_) {
      while (pos_ < text_.size() && text_[pos_] != '\n') ++pos_;
    } else {
      break;
    }
  }
}

bool Scanner::AtEnd() {
  SkipSpace();
  return pos_ >= text_.size();
}

std::string_view Scanner::Token(std::string_view what) {
  SkipSpace();
  if (pos_ >= text_.size()) {
    Fail("unexpected end of file: expected " + std::string(what) + "; the file is truncated");
  }
  size_t start = pos_;
  while (pos_ < text_.size()) {
    char c = text_[pos_];
    if (c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\f' || c == '\v' ||
        (comment_ != '\0' && c == comment_)) {
      break;
    }
    ++pos_;
  }
  return text_.substr(start, pos_ - start);
}

std::string_view Scanner::TokenOnLine() {
  while (pos_ < text_.size()) {
    char c = text_[pos_];
    if (c == ' ' || c == '\t' || c == '\r') {
      ++pos_;
    } else if (comment_ != '\0' && c == comment_) {
      while (pos_ < text_.size() && text_[pos_] != '\n') ++pos_;
    } else {
      break;
    }
  }
  if (pos_ >= text_.size() || text_[pos_] == '\n') return {};
  return Token("a value");
}

std::string_view Scanner::PeekToken(std::string_view what) {
  const size_t pos = pos_;
  const long line = line_;
  const std::string_view token = Token(what);
  pos_ = pos;
  line_ = line;
  return token;
}

long Scanner::Int(std::string_view what) {
  std::string_view token = Token(what);
  long value = 0;
  auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
  if (ec != std::errc() || end != token.data() + token.size()) {
    Fail("expected " + std::string(what) + " (an integer), found '" +
         std::string(token.substr(0, 40)) + "'");
  }
  return value;
}

double Scanner::Double(std::string_view what) {
  std::string_view token = Token(what);
  double value = 0.0;
  const char* first = token.data();
  if (!token.empty() && token[0] == '+') ++first;  // from_chars rejects a leading '+'
  auto [end, ec] = std::from_chars(first, token.data() + token.size(), value);
  if (ec == std::errc::result_out_of_range) {
    Fail(std::string(what) + " '" + std::string(token) + "' is out of the range of a double");
  }
  if (ec != std::errc() || end != token.data() + token.size()) {
    Fail("expected " + std::string(what) + " (a number), found '" +
         std::string(token.substr(0, 40)) + "'");
  }
  return value;
}

void Scanner::Expect(std::string_view expected) {
  std::string_view token = Token(expected);
  if (token != expected) {
    Fail("expected '" + std::string(expected) + "', found '" + std::string(token.substr(0, 40)) +
         "'");
  }
}

void Scanner::SkipLine() {
  while (pos_ < text_.size() && text_[pos_] != '\n') ++pos_;
  if (pos_ < text_.size()) {
    ++pos_;
    ++line_;
  }
}

void Scanner::SkipPast(std::string_view marker) {
  // search line starts only, counting lines as we go
  while (pos_ < text_.size()) {
    size_t end = text_.find('\n', pos_);
    std::string_view current =
        text_.substr(pos_, (end == std::string_view::npos ? text_.size() : end) - pos_);
    if (!current.empty() && current.back() == '\r') current.remove_suffix(1);
    if (current == marker) {
      pos_ = end == std::string_view::npos ? text_.size() : end + 1;
      ++line_;
      return;
    }
    if (end == std::string_view::npos) break;
    pos_ = end + 1;
    ++line_;
  }
  Fail("unexpected end of file: '" + std::string(marker) + "' is missing; the file is truncated");
}

void Scanner::RequireBytes(size_t count, std::string_view what) {
  if (text_.size() - pos_ < count) {
    Fail("unexpected end of file while reading " + std::string(what) + "; the file is truncated");
  }
}

}  // namespace tetcosim

namespace tetcosim {

void Scanner::CheckCount(long count, size_t bytes_each, std::string_view what) {
  if (count < 0) Fail(std::string(what) + " is negative");
  size_t remaining = text_.size() - pos_;
  if (static_cast<unsigned long>(count) > remaining / std::max<size_t>(bytes_each, 1)) {
    Fail("the file claims " + std::to_string(count) + " " + std::string(what) + " but has only " +
         std::to_string(remaining) + " bytes left; the file is truncated or corrupt");
  }
}

}  // namespace tetcosim
