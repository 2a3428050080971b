//! USB: the NXT's bulk endpoints (`transport = "usb"`, or `"usb:SERIAL"` to pick one brick),
//! through `nusb` (pure Rust, no libusb).
//!
//! An NXT on USB is vendor 0x0694 (LEGO), product 0x0002; its interface 0 has one bulk OUT and
//! one bulk IN endpoint. Each telegram is one transfer, without the 2-byte length of the byte
//! streams, and each reply arrives as one packet of at most 64 bytes (nxt-python's `usb`
//! backend writes the telegram and reads 64 bytes the same way). A USB exchange takes a few
//! milliseconds where Bluetooth takes tens.

use std::io::ErrorKind;
use std::time::Duration;

use nusb::MaybeFuture;
use nusb::transfer::{Buffer, Bulk, Direction, EndpointType, In, Out};

use super::link::{Connection, Device, Framing, LinkTiming, LinkTransport, OpenFailure};

/// LEGO's USB vendor id.
pub const LEGO_VENDOR_ID: u16 = 0x0694;
/// The NXT's USB product id.
pub const NXT_PRODUCT_ID: u16 = 0x0002;
/// The largest packet an NXT sends or takes.
const PACKET: usize = 64;
/// How long a write to the brick may take.
const WRITE_TIMEOUT: Duration = Duration::from_millis(500);

/// Where `docs/bridge.md` tells how to let a user open the brick without root.
const UDEV_FIX: &str = "install the udev rule in docs/bridge.md (\"USB permissions\") and \
                        plug the brick in again, or add the user to the group it names";

/// An NXT on USB, as [`find_bricks`] lists it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct UsbBrick {
    /// Its serial number (the brick's Bluetooth address in hexadecimal), if it reports one.
    pub serial: Option<String>,
    /// Bus number.
    pub bus: u8,
    /// Device address on the bus.
    pub address: u8,
}

impl std::fmt::Display for UsbBrick {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "NXT on USB bus {:03} device {:03}",
            self.bus, self.address
        )?;
        match &self.serial {
            Some(s) => write!(f, ", serial {s} (`transport = \"usb:{s}\"`)"),
            None => Ok(()),
        }
    }
}

/// The NXTs plugged in now.
pub fn find_bricks() -> Result<Vec<UsbBrick>, OpenFailure> {
    Ok(nxt_devices()?
        .iter()
        .map(|info| UsbBrick {
            serial: info.serial_number().map(str::to_owned),
            bus: info.busnum(),
            address: info.device_address(),
        })
        .collect())
}

/// Whether this machine shows a USB bus at all (an error no retry cures when it does not).
/// The launch checks it before anything starts.
pub(crate) fn usb_bus() -> Result<(), OpenFailure> {
    nxt_devices().map(drop)
}

/// The NXTs among the USB devices.
fn nxt_devices() -> Result<Vec<nusb::DeviceInfo>, OpenFailure> {
    let devices = nusb::list_devices().wait().map_err(|e| {
        OpenFailure::new(
            format!("cannot list USB devices: {e}"),
            "this machine shows no USB bus (in a container, pass the host's /dev/bus/usb and \
             /sys/bus/usb through)",
        )
        .for_good()
    })?;
    Ok(devices
        .filter(|d| d.vendor_id() == LEGO_VENDOR_ID && d.product_id() == NXT_PRODUCT_ID)
        .collect())
}

/// A brick on USB: the only one plugged in, or the one with a given serial number.
#[derive(Debug, Clone)]
pub struct UsbDevice {
    serial: Option<String>,
}

impl UsbDevice {
    /// The brick with serial number `serial`, or the only one plugged in.
    pub fn new(serial: Option<String>) -> Self {
        Self { serial }
    }

    /// The one brick this device means, among those plugged in.
    fn choose(&self) -> Result<nusb::DeviceInfo, OpenFailure> {
        let mut found = nxt_devices()?;
        let serials = |found: &[nusb::DeviceInfo]| {
            found
                .iter()
                .map(|d| d.serial_number().unwrap_or("none"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        match &self.serial {
            Some(serial) => {
                let listed = serials(&found);
                found
                    .into_iter()
                    .find(|d| d.serial_number() == Some(serial.as_str()))
                    .ok_or_else(|| {
                        OpenFailure::new(
                            format!("no NXT with serial {serial} on USB (found: {listed})"),
                            "plug it in and switch it on; `tes-bridge scan` lists the bricks \
                             it sees",
                        )
                    })
            }
            None if found.len() > 1 => Err(OpenFailure::new(
                format!("{} NXTs on USB (serials {})", found.len(), serials(&found)),
                "name one: `transport = \"usb:SERIAL\"`",
            )),
            None => found.pop().ok_or_else(|| {
                OpenFailure::new(
                    "no NXT on USB",
                    "plug the brick in with its USB cable and switch it on; `tes-bridge scan` \
                     lists the bricks it sees",
                )
            }),
        }
    }
}

/// Talks to a brick over USB (see [`LinkTransport`] for the link's behaviour).
pub type UsbTransport = LinkTransport<UsbDevice>;

impl LinkTransport<UsbDevice> {
    /// A transport that opens the brick with `serial` (or the only one) at its first
    /// transaction.
    pub fn usb(serial: Option<String>, timing: LinkTiming) -> Self {
        Self::new(UsbDevice::new(serial), timing)
    }
}

impl Device for UsbDevice {
    type Connection = UsbConnection;

    fn open(&mut self) -> Result<UsbConnection, OpenFailure> {
        let info = self.choose()?;
        let device = info
            .open()
            .wait()
            .map_err(|e| usb_failure("open the brick", &e))?;
        let interface = device
            .detach_and_claim_interface(0)
            .wait()
            .map_err(|e| usb_failure("claim the brick's interface 0", &e))?;
        let (out_address, in_address) = bulk_endpoints(&interface);
        let outward = interface
            .endpoint::<Bulk, Out>(out_address)
            .map_err(|e| usb_failure("open the brick's bulk OUT endpoint", &e))?;
        let inward = interface
            .endpoint::<Bulk, In>(in_address)
            .map_err(|e| usb_failure("open the brick's bulk IN endpoint", &e))?;
        Ok(UsbConnection::start(outward, inward))
    }

    fn describe(&self) -> String {
        match &self.serial {
            Some(s) => format!("usb:{s}"),
            None => "usb".into(),
        }
    }

    fn framing(&self) -> Framing {
        Framing::Packets
    }
}

/// The interface's bulk OUT and IN endpoint addresses (the NXT's are 0x01 and 0x82).
fn bulk_endpoints(interface: &nusb::Interface) -> (u8, u8) {
    let (mut out_address, mut in_address) = (0x01, 0x82);
    if let Some(alt) = interface.descriptor() {
        for ep in alt.endpoints() {
            if ep.transfer_type() != Bulk::TYPE {
                continue;
            }
            match ep.direction() {
                Direction::Out => out_address = ep.address(),
                Direction::In => in_address = ep.address(),
            }
        }
    }
    (out_address, in_address)
}

/// A USB failure, said as its cause and what to do.
fn usb_failure(doing: &str, e: &nusb::Error) -> OpenFailure {
    let cause = format!("cannot {doing}: {e}");
    match e.kind() {
        nusb::ErrorKind::PermissionDenied => OpenFailure::new(
            format!("{cause}: the brick is there but this user may not open it"),
            UDEV_FIX,
        ),
        nusb::ErrorKind::Busy => OpenFailure::new(
            format!("{cause}: the brick is in use"),
            "another program (nxt-python, NeXT Tools, a second bridge) holds it: close it first",
        ),
        nusb::ErrorKind::Disconnected => OpenFailure::new(
            format!("{cause}: the brick went away"),
            "check the cable and that the brick is on",
        ),
        _ => OpenFailure::bare(cause),
    }
}

/// An open USB link: writes one transfer per telegram, and keeps one IN transfer pending so
/// a reply is taken as soon as the brick sends it.
pub struct UsbConnection {
    outward: nusb::Endpoint<Bulk, Out>,
    inward: nusb::Endpoint<Bulk, In>,
}

impl UsbConnection {
    fn start(outward: nusb::Endpoint<Bulk, Out>, mut inward: nusb::Endpoint<Bulk, In>) -> Self {
        let packet = inward.max_packet_size().max(PACKET);
        inward.submit(Buffer::new(packet));
        Self { outward, inward }
    }

    /// Queues the next IN transfer.
    fn resubmit(&mut self, mut buffer: Buffer) {
        buffer.clear();
        buffer.set_requested_len(self.inward.max_packet_size().max(PACKET));
        self.inward.submit(buffer);
    }
}

impl Connection for UsbConnection {
    fn send(&mut self, frame: &[u8]) -> std::io::Result<()> {
        let mut buffer = Buffer::new(frame.len());
        buffer.extend_from_slice(frame);
        self.outward
            .transfer_blocking(buffer, WRITE_TIMEOUT)
            .status
            .map_err(std::io::Error::from)
    }

    fn receive(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        let Some(completion) = self.inward.wait_next_complete(timeout) else {
            return Err(ErrorKind::TimedOut.into());
        };
        let status = completion.status;
        let n = completion.buffer.len().min(buf.len());
        buf[..n].copy_from_slice(&completion.buffer[..n]);
        self.resubmit(completion.buffer);
        match status {
            Ok(()) if n == 0 => Err(ErrorKind::Interrupted.into()),
            Ok(()) => Ok(n),
            Err(e) => Err(std::io::Error::from(e)),
        }
    }

    fn discard_input(&mut self) {
        while let Some(completion) = self.inward.wait_next_complete(Duration::ZERO) {
            let failed = completion.status.is_err();
            self.resubmit(completion.buffer);
            if failed {
                break;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A brick is shown with the transport line that picks it.
    #[test]
    fn a_brick_says_how_to_pick_it() {
        let brick = UsbBrick {
            serial: Some("0016530A0B0C".into()),
            bus: 1,
            address: 7,
        };
        assert_eq!(
            brick.to_string(),
            "NXT on USB bus 001 device 007, serial 0016530A0B0C (`transport = \"usb:0016530A0B0C\"`)"
        );
        assert_eq!(UsbDevice::new(None).describe(), "usb");
        assert_eq!(UsbDevice::new(Some("X".into())).framing(), Framing::Packets);
    }
}
