// ObjectDictionary: the table of CANopen objects a simulated node serves over SDO and maps into
// PDOs. Every entry has an index, subindex, data type, access type and (for numbers) a value range;
// the SDO server and the PDO engine work only through this table.
#pragma once

#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

namespace tendril::sim {

// Thrown at set-up when the dictionary is built inconsistently (duplicate entry, bad default).
class ObjectDictionaryError : public std::logic_error {
 public:
  using std::logic_error::logic_error;
};

enum class OdType : std::uint8_t { u8, u16, u32, i8, i16, i32, visible_string };
enum class OdAccess : std::uint8_t { read_only, write_only, read_write, constant };

// Size in bytes of a numeric type (visible strings report 0: variable length).
std::size_t od_type_size(OdType type) noexcept;

// Returns 0 to accept a write or an SDO abort code to refuse it. Called before the value is stored.
using OdWriteCheck = std::function<std::uint32_t(std::uint16_t index, std::uint8_t sub, std::int64_t value)>;

struct OdEntry {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  OdType type = OdType::u8;
  OdAccess access = OdAccess::read_only;
  bool pdo_mappable = false;
  std::int64_t minimum = 0;  // inclusive range for numeric writes
  std::int64_t maximum = 0;
  std::int64_t value = 0;  // numeric value, sign-extended for signed types
  std::int64_t default_value = 0;
  std::string text;  // visible strings; capacity reserved at set-up so writes do not allocate
  std::string default_text;
  std::size_t text_capacity = 0;
  bool communication_area() const noexcept { return index >= 0x1000 && index < 0x2000; }
  bool readable() const noexcept { return access != OdAccess::write_only; }
  bool writable() const noexcept { return access == OdAccess::write_only || access == OdAccess::read_write; }
};

class ObjectDictionary {
 public:
  // Set-up: add entries (any order), then freeze() sorts and checks them. Numeric ranges default to
  // the full range of the type.
  OdEntry& add(std::uint16_t index, std::uint8_t sub, OdType type, OdAccess access,
               std::int64_t default_value, bool pdo_mappable = false);
  OdEntry& add_string(std::uint16_t index, std::uint8_t sub, OdAccess access, std::string default_text,
                      std::size_t capacity);
  void set_range(std::uint16_t index, std::uint8_t sub, std::int64_t minimum, std::int64_t maximum);
  void set_write_check(OdWriteCheck check) { write_check_ = std::move(check); }
  void freeze();

  // Lookup (binary search; no allocation). nullptr if absent.
  OdEntry* find(std::uint16_t index, std::uint8_t sub) noexcept;
  const OdEntry* find(std::uint16_t index, std::uint8_t sub) const noexcept;
  bool has_index(std::uint16_t index) const noexcept;
  // Like find() but throws ObjectDictionaryError: for set-up code that caches entry pointers.
  OdEntry& at(std::uint16_t index, std::uint8_t sub);

  // SDO-level access. Both return 0 on success or an SDO abort code.
  // read: copies the little-endian encoding into out (up to out_capacity bytes), sets size.
  std::uint32_t read(std::uint16_t index, std::uint8_t sub, std::uint8_t* out, std::size_t out_capacity,
                     std::size_t& size) const noexcept;
  // write: checks access, length, range and the write check, then stores.
  std::uint32_t write(std::uint16_t index, std::uint8_t sub, const std::uint8_t* data,
                      std::size_t size) noexcept;
  // Size in bytes an upload of this entry produces (0 if absent or not readable).
  std::size_t size_of(std::uint16_t index, std::uint8_t sub) const noexcept;

  // Restores defaults: the communication area (0x1000-0x1FFF) or everything.
  void reset_communication() noexcept;
  void reset_all() noexcept;

  const std::vector<OdEntry>& entries() const noexcept { return entries_; }

 private:
  std::vector<OdEntry> entries_;
  OdWriteCheck write_check_;
  bool frozen_ = false;
};

// Encode / decode a numeric value of `type` as little-endian bytes.
void od_encode(OdType type, std::int64_t value, std::uint8_t* out) noexcept;
std::int64_t od_decode(OdType type, const std::uint8_t* in) noexcept;

}  // namespace tendril::sim
