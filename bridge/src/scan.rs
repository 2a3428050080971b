//! `tes-bridge scan`: the bricks this machine can reach, and plainly why not when it cannot.
//!
//! USB: every NXT plugged in (vendor 0x0694, product 0x0002), each opened once to tell whether
//! this user may use it. Bluetooth: whether the kernel offers Bluetooth sockets, which
//! adapters there are and whether they are on, and the paired NXTs BlueZ knows (asked over the
//! system D-Bus; nothing is discovered or paired here).

use std::collections::HashMap;
use std::path::Path;

use serde::Serialize;
use zbus::zvariant::{OwnedObjectPath, OwnedValue};

use crate::transport::kernel_support;
use crate::transport::{UsbBrick, find_bricks};

/// The NXT's Bluetooth class of device: major class "toy", minor "robot".
const NXT_CLASS: u32 = 0x0804;

/// What a scan found.
#[derive(Debug, Clone, Serialize)]
pub struct Scan {
    /// The NXTs on USB.
    pub usb: Vec<UsbFound>,
    /// Why USB could not be looked at, if it could not.
    pub usb_problem: Option<String>,
    /// The Bluetooth adapters, and why Bluetooth cannot be used, if it cannot.
    pub bluetooth: BluetoothScan,
}

/// An NXT on USB, and whether this user may open it.
#[derive(Debug, Clone, Serialize)]
pub struct UsbFound {
    /// The brick.
    #[serde(flatten)]
    pub brick: UsbBrick,
    /// Why it cannot be opened (permission, in use), if it cannot.
    pub problem: Option<String>,
}

/// What Bluetooth offers here.
#[derive(Debug, Clone, Default, Serialize)]
pub struct BluetoothScan {
    /// Adapters (`hci0`, …) with whether each is on, as the kernel lists them.
    pub adapters: Vec<Adapter>,
    /// Paired devices that look like NXTs (name or class of device).
    pub bricks: Vec<PairedBrick>,
    /// Paired devices that are not NXTs.
    pub other_paired: usize,
    /// Why Bluetooth cannot be used, or why the paired devices are unknown.
    pub problem: Option<String>,
}

/// A Bluetooth adapter.
#[derive(Debug, Clone, Serialize)]
pub struct Adapter {
    /// Its kernel name (`hci0`).
    pub name: String,
    /// Whether it is on (BlueZ's `Powered`), when BlueZ could be asked.
    pub powered: Option<bool>,
}

/// A paired NXT that BlueZ knows.
#[derive(Debug, Clone, Serialize)]
pub struct PairedBrick {
    /// Its address.
    pub address: String,
    /// Its name (the brick's own, "NXT" unless renamed).
    pub name: String,
    /// Whether it is connected now.
    pub connected: bool,
}

/// Looks at USB and Bluetooth.
pub fn scan() -> Scan {
    let (usb, usb_problem) = match find_bricks() {
        Ok(bricks) => (bricks.into_iter().map(check_access).collect(), None),
        Err(e) => (Vec::new(), Some(e.to_string())),
    };
    Scan {
        usb,
        usb_problem,
        bluetooth: scan_bluetooth(Path::new("/sys/class/bluetooth")),
    }
}

impl Scan {
    /// Bricks found (on USB, and paired over Bluetooth).
    pub fn bricks(&self) -> usize {
        self.usb.len() + self.bluetooth.bricks.len()
    }
}

impl std::fmt::Display for Scan {
    /// The report for a person: each link, its bricks with the `transport` line to use, or why
    /// there is none.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.usb_problem, self.usb.len()) {
            (Some(p), _) => writeln!(f, "USB: {p}")?,
            (None, 0) => writeln!(
                f,
                "USB: no NXT plugged in (plug it in with its cable and switch it on)"
            )?,
            (None, n) => writeln!(f, "USB: {n} NXT{}", if n == 1 { "" } else { "s" })?,
        }
        for found in &self.usb {
            match &found.problem {
                None => writeln!(f, "  {}", found.brick)?,
                Some(p) => writeln!(f, "  {}: {p}", found.brick)?,
            }
        }
        write!(f, "{}", self.bluetooth)
    }
}

impl std::fmt::Display for BluetoothScan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let adapters: Vec<String> = self
            .adapters
            .iter()
            .map(|a| match a.powered {
                Some(true) => format!("{} (on)", a.name),
                Some(false) => format!("{} (off: `bluetoothctl power on`)", a.name),
                None => a.name.clone(),
            })
            .collect();
        if let Some(p) = &self.problem {
            return writeln!(f, "Bluetooth: {p}");
        }
        writeln!(
            f,
            "Bluetooth: adapter{} {}; {} paired NXT{}{}",
            if adapters.len() == 1 { "" } else { "s" },
            adapters.join(", "),
            self.bricks.len(),
            if self.bricks.len() == 1 { "" } else { "s" },
            match self.other_paired {
                0 => String::new(),
                n => format!(
                    " ({n} other paired device{})",
                    if n == 1 { "" } else { "s" }
                ),
            }
        )?;
        for b in &self.bricks {
            writeln!(
                f,
                "  {} \"{}\"{} (`transport = \"bluetooth:{}\"`)",
                b.address,
                b.name,
                if b.connected { ", connected" } else { "" },
                b.address
            )?;
        }
        if self.bricks.is_empty() {
            writeln!(
                f,
                "  pair the brick first: `bluetoothctl pair ADDRESS` (the brick asks for a PIN: \
                 1234 by default)"
            )?;
        }
        Ok(())
    }
}

/// Opens `brick` once to tell whether this user may use it.
fn check_access(brick: UsbBrick) -> UsbFound {
    use crate::transport::link::Device;
    let mut device = crate::transport::UsbDevice::new(brick.serial.clone());
    let problem = match (&brick.serial, device.open()) {
        (_, Ok(_)) => None,
        // Several bricks without serial numbers cannot be told apart: no access check.
        (None, Err(_)) => None,
        (Some(_), Err(e)) => Some(e.to_string()),
    };
    UsbFound { brick, problem }
}

/// Bluetooth here: the kernel's support, the adapters `sysfs` lists, then BlueZ's view.
fn scan_bluetooth(sysfs: &Path) -> BluetoothScan {
    if let Err(e) = kernel_support() {
        return BluetoothScan {
            problem: Some(e.to_string()),
            ..BluetoothScan::default()
        };
    }
    let mut scan = BluetoothScan {
        adapters: kernel_adapters(sysfs),
        ..BluetoothScan::default()
    };
    if scan.adapters.is_empty() {
        scan.problem =
            Some("no Bluetooth adapter (plug one in; `bluetoothctl list` should show it)".into());
        return scan;
    }
    if let Err(e) = ask_bluez(&mut scan) {
        scan.problem = Some(format!(
            "cannot ask BlueZ for the paired devices: {e} (is bluetoothd running? \
             `systemctl start bluetooth`)"
        ));
    }
    scan
}

/// The adapters the kernel lists under `sysfs` (`/sys/class/bluetooth/hci0`, …).
fn kernel_adapters(sysfs: &Path) -> Vec<Adapter> {
    let mut names: Vec<String> = std::fs::read_dir(sysfs)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("hci") && !n.contains(':'))
        .collect();
    names.sort();
    names
        .into_iter()
        .map(|name| Adapter {
            name,
            powered: None,
        })
        .collect()
}

/// BlueZ's objects: path → interface → property → value.
type ManagedObjects = HashMap<OwnedObjectPath, HashMap<String, HashMap<String, OwnedValue>>>;

/// Fills in whether each adapter is on and the paired NXTs, from BlueZ over the system D-Bus.
fn ask_bluez(scan: &mut BluetoothScan) -> Result<(), String> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| e.to_string())?;
    let objects: ManagedObjects = runtime.block_on(async {
        let bus = zbus::Connection::system()
            .await
            .map_err(|e| e.to_string())?;
        let reply = bus
            .call_method(
                Some("org.bluez"),
                "/",
                Some("org.freedesktop.DBus.ObjectManager"),
                "GetManagedObjects",
                &(),
            )
            .await
            .map_err(|e| e.to_string())?;
        reply.body().deserialize().map_err(|e| e.to_string())
    })?;
    for (path, interfaces) in &objects {
        if let Some(adapter) = interfaces.get("org.bluez.Adapter1") {
            let name = path.as_str().rsplit('/').next().unwrap_or_default();
            if let Some(a) = scan.adapters.iter_mut().find(|a| a.name == name) {
                a.powered = property(adapter, "Powered");
            }
        }
        let Some(device) = interfaces.get("org.bluez.Device1") else {
            continue;
        };
        if property::<bool>(device, "Paired") != Some(true) {
            continue;
        }
        let name: String = property(device, "Name").unwrap_or_default();
        let class: u32 = property(device, "Class").unwrap_or(0);
        if name.contains("NXT") || class & 0x1FFC == NXT_CLASS {
            scan.bricks.push(PairedBrick {
                address: property(device, "Address").unwrap_or_default(),
                name,
                connected: property(device, "Connected").unwrap_or(false),
            });
        } else {
            scan.other_paired += 1;
        }
    }
    scan.bricks.sort_by(|a, b| a.address.cmp(&b.address));
    Ok(())
}

/// One property of a BlueZ object, if it is there and of type `T`.
fn property<T: TryFrom<OwnedValue>>(props: &HashMap<String, OwnedValue>, key: &str) -> Option<T> {
    props
        .get(key)
        .and_then(|v| v.try_clone().ok())
        .and_then(|v| T::try_from(v).ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a machine without Bluetooth (as the build machine), the scan says so plainly; a
    /// missing `sysfs` class lists no adapter.
    #[test]
    fn bluetooth_says_why_it_cannot_be_used() {
        let scan = scan_bluetooth(Path::new("/nonexistent/class/bluetooth"));
        let problem = scan.problem.expect("no Bluetooth here, one way or another");
        assert!(
            problem.contains("this machine has no Bluetooth")
                || problem.contains("no Bluetooth adapter"),
            "{problem}"
        );
        assert!(kernel_adapters(Path::new("/nonexistent")).is_empty());
    }

    /// Adapters are the `hciN` entries, sorted.
    #[test]
    fn adapters_are_the_hci_entries() {
        let dir = tempfile::tempdir().expect("temp dir");
        for name in ["hci1", "hci0", "hci0:64", "rfkill3"] {
            std::fs::create_dir(dir.path().join(name)).expect("entry");
        }
        let names: Vec<String> = kernel_adapters(dir.path())
            .into_iter()
            .map(|a| a.name)
            .collect();
        assert_eq!(names, ["hci0", "hci1"]);
    }
}
