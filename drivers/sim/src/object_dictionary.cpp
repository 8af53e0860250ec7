#include "tendril/drivers/sim/object_dictionary.hpp"

#include <algorithm>
#include <limits>

#include "tendril/drivers/canopen/protocol.hpp"

namespace tendril::sim {

namespace abort_code = canopen::sdo_abort;

std::size_t od_type_size(OdType type) noexcept {
  switch (type) {
    case OdType::u8:
    case OdType::i8:
      return 1;
    case OdType::u16:
    case OdType::i16:
      return 2;
    case OdType::u32:
    case OdType::i32:
      return 4;
    case OdType::visible_string:
      return 0;
  }
  return 0;
}

namespace {

std::int64_t type_min(OdType t) {
  switch (t) {
    case OdType::i8:
      return std::numeric_limits<std::int8_t>::min();
    case OdType::i16:
      return std::numeric_limits<std::int16_t>::min();
    case OdType::i32:
      return std::numeric_limits<std::int32_t>::min();
    default:
      return 0;
  }
}

std::int64_t type_max(OdType t) {
  switch (t) {
    case OdType::u8:
      return std::numeric_limits<std::uint8_t>::max();
    case OdType::u16:
      return std::numeric_limits<std::uint16_t>::max();
    case OdType::u32:
      return std::numeric_limits<std::uint32_t>::max();
    case OdType::i8:
      return std::numeric_limits<std::int8_t>::max();
    case OdType::i16:
      return std::numeric_limits<std::int16_t>::max();
    case OdType::i32:
      return std::numeric_limits<std::int32_t>::max();
    default:
      return 0;
  }
}

bool key_less(const OdEntry& e, std::uint32_t key) { return ((std::uint32_t{e.index} << 8) | e.sub) < key; }

}  // namespace

void od_encode(OdType type, std::int64_t value, std::uint8_t* out) noexcept {
  const auto raw = static_cast<std::uint64_t>(value);
  const std::size_t n = od_type_size(type);
  for (std::size_t i = 0; i < n; ++i) out[i] = static_cast<std::uint8_t>(raw >> (8 * i));
}

std::int64_t od_decode(OdType type, const std::uint8_t* in) noexcept {
  std::uint64_t raw = 0;
  const std::size_t n = od_type_size(type);
  for (std::size_t i = 0; i < n; ++i) raw |= std::uint64_t{in[i]} << (8 * i);
  switch (type) {
    case OdType::i8:
      return static_cast<std::int8_t>(raw);
    case OdType::i16:
      return static_cast<std::int16_t>(raw);
    case OdType::i32:
      return static_cast<std::int32_t>(raw);
    default:
      return static_cast<std::int64_t>(raw);
  }
}

OdEntry& ObjectDictionary::add(std::uint16_t index, std::uint8_t sub, OdType type, OdAccess access,
                               std::int64_t default_value, bool pdo_mappable) {
  if (frozen_) throw ObjectDictionaryError("object dictionary: add() after freeze()");
  if (type == OdType::visible_string)
    throw ObjectDictionaryError("object dictionary: use add_string() for strings");
  OdEntry e;
  e.index = index;
  e.sub = sub;
  e.type = type;
  e.access = access;
  e.pdo_mappable = pdo_mappable;
  e.minimum = type_min(type);
  e.maximum = type_max(type);
  if (default_value < e.minimum || default_value > e.maximum) {
    throw ObjectDictionaryError("object dictionary: default of entry " + std::to_string(index) + ":" +
                                std::to_string(sub) + " does not fit its type");
  }
  e.value = e.default_value = default_value;
  entries_.push_back(std::move(e));
  return entries_.back();
}

OdEntry& ObjectDictionary::add_string(std::uint16_t index, std::uint8_t sub, OdAccess access,
                                      std::string default_text, std::size_t capacity) {
  if (frozen_) throw ObjectDictionaryError("object dictionary: add_string() after freeze()");
  if (default_text.size() > capacity)
    throw ObjectDictionaryError("object dictionary: default string exceeds capacity");
  OdEntry e;
  e.index = index;
  e.sub = sub;
  e.type = OdType::visible_string;
  e.access = access;
  e.text_capacity = capacity;
  e.text.reserve(capacity);
  e.text = default_text;
  e.default_text = std::move(default_text);
  entries_.push_back(std::move(e));
  return entries_.back();
}

void ObjectDictionary::set_range(std::uint16_t index, std::uint8_t sub, std::int64_t minimum,
                                 std::int64_t maximum) {
  for (auto& e : entries_) {
    if (e.index == index && e.sub == sub) {
      e.minimum = minimum;
      e.maximum = maximum;
      return;
    }
  }
  throw ObjectDictionaryError("object dictionary: set_range on a missing entry");
}

void ObjectDictionary::freeze() {
  std::sort(entries_.begin(), entries_.end(), [](const OdEntry& a, const OdEntry& b) {
    return a.index != b.index ? a.index < b.index : a.sub < b.sub;
  });
  for (std::size_t i = 1; i < entries_.size(); ++i) {
    if (entries_[i].index == entries_[i - 1].index && entries_[i].sub == entries_[i - 1].sub) {
      throw ObjectDictionaryError("object dictionary: duplicate entry " + std::to_string(entries_[i].index) +
                                  ":" + std::to_string(entries_[i].sub));
    }
  }
  // Strings reserved before the move may have lost their capacity; reserve again now.
  for (auto& e : entries_) {
    if (e.type == OdType::visible_string) e.text.reserve(e.text_capacity);
  }
  frozen_ = true;
}

OdEntry* ObjectDictionary::find(std::uint16_t index, std::uint8_t sub) noexcept {
  const std::uint32_t key = (std::uint32_t{index} << 8) | sub;
  auto it = std::lower_bound(entries_.begin(), entries_.end(), key, key_less);
  if (it == entries_.end() || it->index != index || it->sub != sub) return nullptr;
  return &*it;
}

const OdEntry* ObjectDictionary::find(std::uint16_t index, std::uint8_t sub) const noexcept {
  return const_cast<ObjectDictionary*>(this)->find(index, sub);
}

bool ObjectDictionary::has_index(std::uint16_t index) const noexcept {
  const std::uint32_t key = std::uint32_t{index} << 8;
  auto it = std::lower_bound(entries_.begin(), entries_.end(), key, key_less);
  return it != entries_.end() && it->index == index;
}

OdEntry& ObjectDictionary::at(std::uint16_t index, std::uint8_t sub) {
  if (auto* e = find(index, sub)) return *e;
  throw ObjectDictionaryError("object dictionary: no entry " + std::to_string(index) + ":" +
                              std::to_string(sub));
}

std::size_t ObjectDictionary::size_of(std::uint16_t index, std::uint8_t sub) const noexcept {
  const auto* e = find(index, sub);
  if (!e || !e->readable()) return 0;
  return e->type == OdType::visible_string ? e->text.size() : od_type_size(e->type);
}

std::uint32_t ObjectDictionary::read(std::uint16_t index, std::uint8_t sub, std::uint8_t* out,
                                     std::size_t out_capacity, std::size_t& size) const noexcept {
  size = 0;
  const auto* e = find(index, sub);
  if (!e) return has_index(index) ? abort_code::no_subindex : abort_code::no_object;
  if (!e->readable()) return abort_code::write_only;
  if (e->type == OdType::visible_string) {
    if (e->text.size() > out_capacity) return abort_code::out_of_memory;
    // SDO strings carry an explicit length and no terminator, so copy the bytes only.
    std::copy(e->text.begin(), e->text.end(), out);
    size = e->text.size();
    return 0;
  }
  const std::size_t n = od_type_size(e->type);
  if (n > out_capacity) return abort_code::out_of_memory;
  od_encode(e->type, e->value, out);
  size = n;
  return 0;
}

std::uint32_t ObjectDictionary::write(std::uint16_t index, std::uint8_t sub, const std::uint8_t* data,
                                      std::size_t size) noexcept {
  auto* e = find(index, sub);
  if (!e) return has_index(index) ? abort_code::no_subindex : abort_code::no_object;
  if (!e->writable()) return abort_code::read_only;
  if (e->type == OdType::visible_string) {
    if (size > e->text_capacity) return abort_code::length_too_high;
    if (write_check_) {
      if (auto code = write_check_(index, sub, static_cast<std::int64_t>(size))) return code;
    }
    e->text.assign(reinterpret_cast<const char*>(data), size);  // within reserved capacity
    return 0;
  }
  const std::size_t n = od_type_size(e->type);
  if (size != n) return abort_code::length_mismatch;
  const std::int64_t v = od_decode(e->type, data);
  if (v < e->minimum || v > e->maximum) return abort_code::value_range;
  if (write_check_) {
    if (auto code = write_check_(index, sub, v)) return code;
  }
  e->value = v;
  return 0;
}

void ObjectDictionary::reset_communication() noexcept {
  for (auto& e : entries_) {
    if (!e.communication_area()) continue;
    e.value = e.default_value;
    if (e.type == OdType::visible_string) e.text.assign(e.default_text);
  }
}

void ObjectDictionary::reset_all() noexcept {
  for (auto& e : entries_) {
    e.value = e.default_value;
    if (e.type == OdType::visible_string) e.text.assign(e.default_text);
  }
}

}  // namespace tendril::sim
