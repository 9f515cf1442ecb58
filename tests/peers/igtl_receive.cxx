// A receive client built on the OpenIGTLink C++ library (Debian's libopenigtlink-dev), compiled
// by the tests: connects to HOST PORT, optionally asks for tracking data every TDATA_MS ms
// (STT_TDATA), and prints one line per message it receives until the server closes the
// connection. Every body is unpacked by the library with its CRC check.
//
// TRANSFORM name sec nanosec crc_ok m11 m21 m31 m12 m22 m32 m13 m23 m33 tx ty tz
// STATUS name sec nanosec crc_ok code subcode error_name|message
// TDATA name sec nanosec crc_ok elements [element_name m11 … tz]...
// RTS_TDATA name sec nanosec crc_ok status
// OTHER type name sec nanosec body_bytes
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include "igtlClientSocket.h"
#include "igtlMessageHeader.h"
#include "igtlStatusMessage.h"
#include "igtlTrackingDataMessage.h"
#include "igtlTransformMessage.h"

static void print_matrix(igtl::Matrix4x4& m) {
  for (int c = 0; c < 4; c++)
    for (int r = 0; r < 3; r++) std::printf(" %.9g", m[r][c]);
}

template <class M>
static int receive(igtl::ClientSocket* socket, igtl::MessageHeader::Pointer& header, M& msg) {
  msg->SetMessageHeader(header);
  msg->AllocatePack();
  if (msg->GetPackBodySize() > 0) socket->Receive(msg->GetPackBodyPointer(), msg->GetPackBodySize());
  return (msg->Unpack(1) & igtl::MessageHeader::UNPACK_BODY) ? 1 : 0;
}

int main(int argc, char* argv[]) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s HOST PORT [TDATA_MS]\n", argv[0]);
    return 2;
  }
  igtl::ClientSocket::Pointer socket = igtl::ClientSocket::New();
  if (socket->ConnectToServer(argv[1], std::atoi(argv[2])) != 0) {
    std::fprintf(stderr, "cannot connect to %s:%s\n", argv[1], argv[2]);
    return 1;
  }
  if (argc > 3) {
    igtl::StartTrackingDataMessage::Pointer start = igtl::StartTrackingDataMessage::New();
    start->SetDeviceName("ToolToArmBase");
    start->SetResolution(std::atoi(argv[3]));
    start->SetCoordinateName("");
    start->Pack();
    socket->Send(start->GetPackPointer(), start->GetPackSize());
  }
  std::printf("CONNECTED\n");
  std::fflush(stdout);
  igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
  for (;;) {
    header->InitPack();
    int r = socket->Receive(header->GetPackPointer(), header->GetPackSize());
    if (r != header->GetPackSize()) break;  // closed
    header->Unpack();
    unsigned int sec = 0, frac = 0;
    igtl::TimeStamp::Pointer ts = igtl::TimeStamp::New();
    header->GetTimeStamp(ts);
    ts->GetTimeStamp(&sec, &frac);  // frac: nanoseconds here
    const char* type = header->GetDeviceType();
    const char* name = header->GetDeviceName();
    if (std::strcmp(type, "TRANSFORM") == 0) {
      igtl::TransformMessage::Pointer msg = igtl::TransformMessage::New();
      int ok = receive(socket.GetPointer(), header, msg);
      igtl::Matrix4x4 m;
      msg->GetMatrix(m);
      std::printf("TRANSFORM %s %u %u %d", name, sec, frac, ok);
      print_matrix(m);
      std::printf("\n");
    } else if (std::strcmp(type, "STATUS") == 0) {
      igtl::StatusMessage::Pointer msg = igtl::StatusMessage::New();
      int ok = receive(socket.GetPointer(), header, msg);
      std::printf("STATUS %s %u %u %d %d %lld %s|%s\n", name, sec, frac, ok, msg->GetCode(),
                  (long long)msg->GetSubCode(), msg->GetErrorName(), msg->GetStatusString());
    } else if (std::strcmp(type, "TDATA") == 0) {
      igtl::TrackingDataMessage::Pointer msg = igtl::TrackingDataMessage::New();
      int ok = receive(socket.GetPointer(), header, msg);
      int n = msg->GetNumberOfTrackingDataElements();
      std::printf("TDATA %s %u %u %d %d", name, sec, frac, ok, n);
      for (int i = 0; i < n; i++) {
        igtl::TrackingDataElement::Pointer e;
        msg->GetTrackingDataElement(i, e);
        igtl::Matrix4x4 m;
        e->GetMatrix(m);
        std::printf(" %s", e->GetName());
        print_matrix(m);
      }
      std::printf("\n");
    } else if (std::strcmp(type, "RTS_TDATA") == 0) {
      igtl::RTSTrackingDataMessage::Pointer msg = igtl::RTSTrackingDataMessage::New();
      int ok = receive(socket.GetPointer(), header, msg);
      std::printf("RTS_TDATA %s %u %u %d %d\n", name, sec, frac, ok, msg->GetStatus());
    } else {
      std::printf("OTHER %s %s %u %u %d\n", type, name, sec, frac, header->GetBodySizeToRead());
      socket->Skip(header->GetBodySizeToRead(), 0);
    }
  }
  std::printf("CLOSED\n");
  return 0;
}
