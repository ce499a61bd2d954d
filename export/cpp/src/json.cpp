// The small JSON reader behind slimseg::Json (metadata sidecars and ONNX metadata_props).
#include "slimseg/json.hpp"

#include <charconv>
#include <cstring>

namespace slimseg {
namespace {

class Parser {
public:
    Parser(const std::string& text, const std::string& what) : s_(text), what_(what) {}

    Json document() {
        Json v = value(0);
        skip_space();
        if (pos_ != s_.size()) fail("unexpected text after the JSON value");
        return v;
    }

private:
    const std::string& s_;
    const std::string& what_;
    size_t pos_ = 0;

    [[noreturn]] void fail(const std::string& why) const {
        throw Error("JSON (" + what_ + "): " + why + " at offset " + std::to_string(pos_));
    }
    void skip_space() {
        while (pos_ < s_.size() && std::strchr(" \t\r\n", s_[pos_]) != nullptr && s_[pos_]) ++pos_;
    }
    bool eat(char c) {
        skip_space();
        if (pos_ < s_.size() && s_[pos_] == c) {
            ++pos_;
            return true;
        }
        return false;
    }
    void expect_word(const char* word) {
        size_t n = std::strlen(word);
        if (s_.compare(pos_, n, word) != 0) fail(std::string("expected '") + word + "'");
        pos_ += n;
    }

    Json value(int depth) {
        if (depth > 64) fail("nesting deeper than 64");
        skip_space();
        if (pos_ >= s_.size()) fail("unexpected end of text");
        Json v;
        char c = s_[pos_];
        if (c == '{') {
            ++pos_;
            v.kind = Json::Kind::Object;
            if (eat('}')) return v;
            do {
                skip_space();
                if (pos_ >= s_.size() || s_[pos_] != '"') fail("expected a member name");
                std::string key = string_body();
                if (!eat(':')) fail("expected ':'");
                v.object.emplace_back(std::move(key), value(depth + 1));
            } while (eat(','));
            if (!eat('}')) fail("expected ',' or '}'");
        } else if (c == '[') {
            ++pos_;
            v.kind = Json::Kind::Array;
            if (eat(']')) return v;
            do {
                v.array.push_back(value(depth + 1));
            } while (eat(','));
            if (!eat(']')) fail("expected ',' or ']'");
        } else if (c == '"') {
            v.kind = Json::Kind::String;
            v.string = string_body();
        } else if (c == 't') {
            expect_word("true");
            v.kind = Json::Kind::Bool;
            v.boolean = true;
        } else if (c == 'f') {
            expect_word("false");
            v.kind = Json::Kind::Bool;
        } else if (c == 'n') {
            expect_word("null");
        } else if (c == 'N' || c == 'I') {  // Python's json.dumps writes NaN / Infinity
            fail("NaN/Infinity is not JSON");
        } else {
            v.kind = Json::Kind::Number;
            v.number = number();
        }
        return v;
    }

    double number() {
        size_t start = pos_;
        if (pos_ < s_.size() && s_[pos_] == '-') ++pos_;
        while (pos_ < s_.size() && std::strchr("0123456789+-.eE", s_[pos_]) != nullptr &&
               s_[pos_])
            ++pos_;
        double out = 0.0;
        auto res = std::from_chars(s_.data() + start, s_.data() + pos_, out);
        if (res.ec != std::errc() || res.ptr != s_.data() + pos_ || pos_ == start) {
            pos_ = start;
            fail("malformed number");
        }
        return out;
    }

    unsigned hex4() {
        if (pos_ + 4 > s_.size()) fail("truncated \\u escape");
        unsigned v = 0;
        for (int i = 0; i < 4; ++i) {
            char c = s_[pos_++];
            v <<= 4;
            if (c >= '0' && c <= '9') v |= unsigned(c - '0');
            else if (c >= 'a' && c <= 'f') v |= unsigned(c - 'a' + 10);
            else if (c >= 'A' && c <= 'F') v |= unsigned(c - 'A' + 10);
            else fail("bad \\u escape");
        }
        return v;
    }

    static void utf8(std::string& out, unsigned cp) {
        if (cp < 0x80) {
            out += char(cp);
        } else if (cp < 0x800) {
            out += char(0xC0 | (cp >> 6));
            out += char(0x80 | (cp & 0x3F));
        } else if (cp < 0x10000) {
            out += char(0xE0 | (cp >> 12));
            out += char(0x80 | ((cp >> 6) & 0x3F));
            out += char(0x80 | (cp & 0x3F));
        } else {
            out += char(0xF0 | (cp >> 18));
            out += char(0x80 | ((cp >> 12) & 0x3F));
            out += char(0x80 | ((cp >> 6) & 0x3F));
            out += char(0x80 | (cp & 0x3F));
        }
    }

    std::string string_body() {
        ++pos_;  // opening quote
        std::string out;
        while (true) {
            if (pos_ >= s_.size()) fail("unterminated string");
            char c = s_[pos_++];
            if (c == '"') return out;
            if (static_cast<unsigned char>(c) < 0x20) fail("control character in a string");
            if (c != '\\') {
                out += c;
                continue;
            }
            if (pos_ >= s_.size()) fail("unterminated escape");
            char e = s_[pos_++];
            switch (e) {
                case '"': out += '"'; break;
                case '\\': out += '\\'; break;
                case '/': out += '/'; break;
                case 'b': out += '\b'; break;
                case 'f': out += '\f'; break;
                case 'n': out += '\n'; break;
                case 'r': out += '\r'; break;
                case 't': out += '\t'; break;
                case 'u': {
                    unsigned cp = hex4();
                    if (cp >= 0xD800 && cp < 0xDC00) {  // surrogate pair
                        if (s_.compare(pos_, 2, "\\u") != 0) fail("lone surrogate");
                        pos_ += 2;
                        unsigned lo = hex4();
                        if (lo < 0xDC00 || lo >= 0xE000) fail("bad surrogate pair");
                        cp = 0x10000 + ((cp - 0xD800) << 10) + (lo - 0xDC00);
                    }
                    utf8(out, cp);
                    break;
                }
                default: fail("bad escape");
            }
        }
    }
};

}  // namespace

Json Json::parse(const std::string& text, const std::string& what) {
    return Parser(text, what).document();
}

const Json* Json::find(const std::string& key) const {
    if (kind != Kind::Object) return nullptr;
    for (const auto& kv : object)
        if (kv.first == key) return &kv.second;
    return nullptr;
}

}  // namespace slimseg
