#pragma once

// LCM's UDP multicast wire format written by hand, for tests that send raw datagrams: what
// liblcm 1.3.1's lcm_udpm_publish sends for one message (bus/udpm.h has the format), and a
// socket that sends datagrams to a udpm:// group as any stranger on the host can.

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "bus/udpm.h"

namespace stackgen::testing {

/// liblcm's limits (lcm/udpm_util.h, Linux): a message whose channel, NUL and bytes fit this is
/// sent in one LC02 datagram; a larger one in LC03 fragments of this many bytes after the header.
inline constexpr size_t kLcmShortMessageMax = 65499;
inline constexpr size_t kLcmFragmentPayload = 65487;

inline void PutBigEndian(uint64_t value, int bytes, std::vector<uint8_t>* out) {
  for (int i = bytes - 1; i >= 0; --i) out->push_back(static_cast<uint8_t>(value >> (8 * i)));
}

/// An LC03 fragment header: magic, seqno, message size, offset, fragment number and count.
inline std::vector<uint8_t> LcmFragmentHeader(uint32_t seqno, uint32_t size, uint32_t offset,
                                              uint16_t number, uint16_t count) {
  std::vector<uint8_t> header;
  PutBigEndian(0x4c433033, 4, &header);
  PutBigEndian(seqno, 4, &header);
  PutBigEndian(size, 4, &header);
  PutBigEndian(offset, 4, &header);
  PutBigEndian(number, 2, &header);
  PutBigEndian(count, 2, &header);
  return header;
}

/// The datagrams liblcm sends for `payload` on `channel` as its message `seqno`.
inline std::vector<std::vector<uint8_t>> LcmDatagrams(const std::string& channel,
                                                      const std::vector<uint8_t>& payload,
                                                      uint32_t seqno) {
  std::vector<std::vector<uint8_t>> datagrams;
  if (channel.size() + 1 + payload.size() <= kLcmShortMessageMax) {
    std::vector<uint8_t> datagram;
    PutBigEndian(0x4c433032, 4, &datagram);
    PutBigEndian(seqno, 4, &datagram);
    datagram.insert(datagram.end(), channel.begin(), channel.end());
    datagram.push_back(0);
    datagram.insert(datagram.end(), payload.begin(), payload.end());
    datagrams.push_back(datagram);
    return datagrams;
  }
  const size_t total = channel.size() + 1 + payload.size();
  const size_t count = (total + kLcmFragmentPayload - 1) / kLcmFragmentPayload;
  size_t offset = 0;
  for (size_t number = 0; number < count; ++number) {
    std::vector<uint8_t> datagram = LcmFragmentHeader(
        seqno, static_cast<uint32_t>(payload.size()), static_cast<uint32_t>(offset),
        static_cast<uint16_t>(number), static_cast<uint16_t>(count));
    size_t room = kLcmFragmentPayload;
    if (number == 0) {
      datagram.insert(datagram.end(), channel.begin(), channel.end());
      datagram.push_back(0);
      room -= channel.size() + 1;
    }
    const size_t length = std::min(room, payload.size() - offset);
    datagram.insert(datagram.end(), payload.begin() + static_cast<std::ptrdiff_t>(offset),
                    payload.begin() + static_cast<std::ptrdiff_t>(offset + length));
    offset += length;
    datagrams.push_back(datagram);
  }
  return datagrams;
}

/// A UDP socket that sends raw datagrams to the group of a udpm:// URL (TTL 0: this host only).
class RawMulticastSender {
 public:
  explicit RawMulticastSender(const std::string& url) {
    const UdpmAddress address = ParseUdpmUrl(url);
    fd_ = socket(AF_INET, SOCK_DGRAM, 0);
    if (fd_ < 0) throw std::runtime_error("cannot open a UDP socket");
    const unsigned char ttl = 0;
    setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_TTL, &ttl, sizeof(ttl));
    to_.sin_family = AF_INET;
    to_.sin_port = htons(address.port);
    to_.sin_addr.s_addr = htonl(address.group);
  }
  ~RawMulticastSender() { close(fd_); }
  RawMulticastSender(const RawMulticastSender&) = delete;
  RawMulticastSender& operator=(const RawMulticastSender&) = delete;

  /// Sends one datagram; false when the kernel refused it (e.g. a full send buffer).
  bool Send(const std::vector<uint8_t>& datagram) const {
    return sendto(fd_, datagram.data(), datagram.size(), 0, reinterpret_cast<const sockaddr*>(&to_),
                  sizeof(to_)) == static_cast<ssize_t>(datagram.size());
  }

 private:
  int fd_ = -1;
  sockaddr_in to_{};
};

}  // namespace stackgen::testing
