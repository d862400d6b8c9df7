// UdpmSender (bus/udpm.h): LCM's wire format onto a udpm:// group, within the MTU, and the
// fragments a receiver missed sent again.

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <deque>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "bus/udpm.h"
#include "bus/udpm_wire.h"

namespace stackgen {

using udpm_wire::Errno;
using udpm_wire::kLongHeaderBytes;
using udpm_wire::kMagicLong;
using udpm_wire::kMagicShort;
using udpm_wire::kMaxChannelBytes;
using udpm_wire::kShortHeaderBytes;
using udpm_wire::PutU32;
using udpm_wire::SteadySeconds;

struct UdpmSender::Impl {
  // a fragmented message sent lately, kept for repairs
  struct Sent {
    uint32_t seqno = 0;
    std::string channel;
    std::vector<uint8_t> bytes;
    uint16_t fragments = 0;
    std::vector<double> resent_s;  // by fragment: when last sent again (0: never)
  };

  int socket_fd = -1;
  sockaddr_in to{};
  std::string where;
  uint16_t port = 0;
  size_t max_datagram = 0;  // UDP payload bytes
  size_t max_kept_bytes = 0;

  std::mutex mutex;  // guards what follows
  uint32_t next_seqno = 0;
  std::deque<Sent> kept;
  size_t kept_bytes = 0;
  int64_t repaired = 0;
  std::vector<uint8_t> datagram;

  ~Impl() {
    if (socket_fd >= 0) close(socket_fd);
  }

  // the message bytes a fragment carries beside the header (fragment 0: the channel too)
  size_t FragmentCapacity() const { return max_datagram - kLongHeaderBytes; }

  // sends datagram[0, size); with the lock held
  void SendDatagram(size_t size, const std::string& channel) {
    for (int attempt = 0;; ++attempt) {
      const ssize_t sent = sendto(socket_fd, datagram.data(), size, 0,
                                  reinterpret_cast<const sockaddr*>(&to), sizeof(to));
      if (sent == static_cast<ssize_t>(size)) return;
      // the interface's queue is full: wait for it a little, as a blocking socket would
      if (sent < 0 && (errno == ENOBUFS || errno == EAGAIN || errno == EINTR) && attempt < 100) {
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
        continue;
      }
      throw std::runtime_error("cannot send on channel " + channel + " to " + where + ": " +
                               Errno("sendto"));
    }
  }

  // sends fragment `number` of `message`; with the lock held
  void SendFragment(const Sent& message, uint16_t number) {
    const size_t channel_bytes = message.channel.size() + 1;
    const size_t capacity = FragmentCapacity();
    // the message's bytes are the channel and the data, cut into pieces of `capacity`
    const size_t start = size_t{number} * capacity;
    const size_t stop = std::min(start + capacity, channel_bytes + message.bytes.size());
    const uint32_t offset = static_cast<uint32_t>(number == 0 ? 0 : start - channel_bytes);
    datagram.resize(kLongHeaderBytes + (stop - start));
    uint8_t* out = datagram.data();
    PutU32(out, kMagicLong);
    PutU32(out + 4, message.seqno);
    PutU32(out + 8, static_cast<uint32_t>(message.bytes.size()));
    PutU32(out + 12, offset);
    out[16] = static_cast<uint8_t>(number >> 8);
    out[17] = static_cast<uint8_t>(number);
    out[18] = static_cast<uint8_t>(message.fragments >> 8);
    out[19] = static_cast<uint8_t>(message.fragments);
    out += kLongHeaderBytes;
    if (number == 0) {
      std::memcpy(out, message.channel.c_str(), channel_bytes);
      out += channel_bytes;
    }
    const size_t data_begin = number == 0 ? 0 : start - channel_bytes;
    const size_t data_end = stop - channel_bytes;
    std::memcpy(out, message.bytes.data() + data_begin, data_end - data_begin);
    SendDatagram(datagram.size(), message.channel);
  }
};

namespace {

// the MTU of the interface the route to `to` takes, or 0 when it cannot be told
int RouteMtu(const sockaddr_in& to) {
  const int fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return 0;
  int mtu = 0;
  socklen_t length = sizeof(mtu);
  if (connect(fd, reinterpret_cast<const sockaddr*>(&to), sizeof(to)) != 0 ||
      getsockopt(fd, IPPROTO_IP, IP_MTU, &mtu, &length) != 0) {
    mtu = 0;
  }
  close(fd);
  return mtu;
}

}  // namespace

UdpmSender::UdpmSender(const UdpmAddress& address, size_t max_kept_bytes)
    : impl_(std::make_unique<Impl>()) {
  Impl& impl = *impl_;
  impl.max_kept_bytes = max_kept_bytes;
  impl.to.sin_family = AF_INET;
  impl.to.sin_addr.s_addr = htonl(address.group);
  impl.to.sin_port = htons(address.port);
  char group_text[INET_ADDRSTRLEN] = "?";
  inet_ntop(AF_INET, &impl.to.sin_addr, group_text, sizeof(group_text));
  impl.where = std::string(group_text) + ":" + std::to_string(address.port);
  const auto fail = [&impl](const std::string& call) {
    throw std::runtime_error("cannot send to multicast group " + impl.where + ": " + Errno(call));
  };
  impl.socket_fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (impl.socket_fd < 0) fail("socket");
  const unsigned char ttl = static_cast<unsigned char>(address.ttl);
  if (setsockopt(impl.socket_fd, IPPROTO_IP, IP_MULTICAST_TTL, &ttl, sizeof(ttl)) < 0) {
    fail("setsockopt(IP_MULTICAST_TTL)");
  }
  const unsigned char loop = 1;
  if (setsockopt(impl.socket_fd, IPPROTO_IP, IP_MULTICAST_LOOP, &loop, sizeof(loop)) < 0) {
    fail("setsockopt(IP_MULTICAST_LOOP)");
  }
  // a port of its own now, so that receivers' repair asks can name it
  sockaddr_in local{};
  local.sin_family = AF_INET;
  local.sin_addr.s_addr = htonl(INADDR_ANY);
  if (bind(impl.socket_fd, reinterpret_cast<const sockaddr*>(&local), sizeof(local)) < 0) {
    fail("bind");
  }
  socklen_t length = sizeof(local);
  if (getsockname(impl.socket_fd, reinterpret_cast<sockaddr*>(&local), &length) < 0) {
    fail("getsockname");
  }
  impl.port = ntohs(local.sin_port);
  int mtu = address.mtu;
  if (mtu == 0) mtu = address.ttl == 0 ? 65535 : RouteMtu(impl.to);
  if (mtu < 576) mtu = 1500;  // the route's MTU could not be told: Ethernet's
  // IPv4 and UDP headers (20 + 8 bytes); a UDP payload is 65507 bytes at most
  impl.max_datagram = std::min<size_t>(static_cast<size_t>(mtu) - 28, 65507);
}

UdpmSender::~UdpmSender() = default;

void UdpmSender::Send(const std::string& channel, const uint8_t* data, size_t size) {
  Impl& impl = *impl_;
  if (channel.empty() || channel.size() > kMaxChannelBytes) {
    throw std::runtime_error("cannot send on channel '" + channel + "': a channel is 1.." +
                             std::to_string(kMaxChannelBytes) + " bytes");
  }
  const std::lock_guard<std::mutex> lock(impl.mutex);
  const uint32_t seqno = impl.next_seqno++;
  const size_t channel_bytes = channel.size() + 1;
  if (kShortHeaderBytes + channel_bytes + size <= impl.max_datagram) {
    impl.datagram.resize(kShortHeaderBytes + channel_bytes + size);
    PutU32(impl.datagram.data(), kMagicShort);
    PutU32(impl.datagram.data() + 4, seqno);
    std::memcpy(impl.datagram.data() + kShortHeaderBytes, channel.c_str(), channel_bytes);
    if (size > 0) {
      std::memcpy(impl.datagram.data() + kShortHeaderBytes + channel_bytes, data, size);
    }
    impl.SendDatagram(impl.datagram.size(), channel);
    return;
  }
  const size_t capacity = impl.FragmentCapacity();
  const size_t fragments = (channel_bytes + size + capacity - 1) / capacity;
  if (fragments > 65535 || size > UINT32_MAX) {
    throw std::runtime_error("cannot send " + std::to_string(size) + " bytes on channel " +
                             channel + " to " + impl.where + ": more than 65535 datagrams of " +
                             std::to_string(impl.max_datagram) + " bytes (raise mtu=)");
  }
  Impl::Sent sent;
  sent.seqno = seqno;
  sent.channel = channel;
  sent.bytes.assign(data, data + size);
  sent.fragments = static_cast<uint16_t>(fragments);
  sent.resent_s.assign(fragments, 0.0);
  for (size_t number = 0; number < fragments; ++number) {
    impl.SendFragment(sent, static_cast<uint16_t>(number));
  }
  // kept for repairs, the oldest giving way (the newest is always kept)
  impl.kept_bytes += sent.bytes.size();
  impl.kept.push_back(std::move(sent));
  while (impl.kept.size() > 1 && impl.kept_bytes > impl.max_kept_bytes) {
    impl.kept_bytes -= impl.kept.front().bytes.size();
    impl.kept.pop_front();
  }
}

int UdpmSender::Repair(const UdpmRepair& repair) {
  Impl& impl = *impl_;
  if ((repair.sender & 0xFFFF) != impl.port) return 0;
  const std::lock_guard<std::mutex> lock(impl.mutex);
  const auto found = std::find_if(impl.kept.begin(), impl.kept.end(), [&](const Impl::Sent& sent) {
    return sent.seqno == repair.seqno && sent.bytes.size() == repair.size &&
           sent.fragments == repair.fragments;
  });
  if (found == impl.kept.end()) return 0;
  const double now_s = SteadySeconds();
  int count = 0;
  const size_t bits = std::min<size_t>(repair.missing.size() * 8, kMaxRepairBits);
  for (size_t i = 0; i < bits; ++i) {
    if ((repair.missing[i / 8] & (1u << (i % 8))) == 0) continue;
    const uint64_t number = uint64_t{repair.first} + i;
    if (number >= found->fragments) break;
    double& resent = found->resent_s[number];
    if (resent > 0 && now_s - resent < 0.01) continue;
    resent = now_s;
    impl.SendFragment(*found, static_cast<uint16_t>(number));
    ++count;
  }
  impl.repaired += count;
  return count;
}

uint16_t UdpmSender::port() const { return impl_->port; }

size_t UdpmSender::max_datagram() const { return impl_->max_datagram; }

int64_t UdpmSender::repaired_fragments() const {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->repaired;
}

}  // namespace stackgen
