//! Streaming images to the tev image viewer over its TCP protocol (`--display-server
//! HOST:PORT`), as pbrt-v4's display does: a `CreateImage` packet when the image's size or
//! channels change, then `UpdateImage` packets (version 3: per-channel offset and stride) of
//! bands of rows, every float channel of the image under its EXR name (but Cryptomatte's).
//!
//! A packet is its length (u32, little-endian, the length field included), a type byte and
//! the fields: bools as one byte, strings NUL-terminated, integers little-endian, pixel data
//! as f32.

use super::{ChannelData, Image};
use std::io::Write;
use std::net::TcpStream;

/// tev's packet type of `CreateImage`.
pub const CREATE_IMAGE: u8 = 4;
/// tev's packet type of `UpdateImage` with per-channel offsets and strides.
pub const UPDATE_IMAGE_V3: u8 = 6;

/// The most pixel data one `UpdateImage` packet carries (floats): tev buffers a packet whole.
const MAX_PACKET_FLOATS: usize = 1 << 20;

/// A connection to a tev instance showing one image.
pub struct DisplayServer {
    stream: TcpStream,
    name: String,
    /// Size and channel names of the image tev holds (`None`: not created yet).
    shown: Option<(usize, usize, Vec<String>)>,
}

impl DisplayServer {
    /// Connects to tev at `address` (`HOST:PORT`); images appear under `name`.
    pub fn connect(address: &str, name: &str) -> Result<DisplayServer, String> {
        let stream =
            TcpStream::connect(address).map_err(|e| format!("cannot reach the display server at {address}: {e}"))?;
        let _ = stream.set_nodelay(true);
        Ok(DisplayServer { stream, name: name.to_string(), shown: None })
    }

    /// Sends `image`'s float channels but Cryptomatte's (ID hashes and coverage ranks, not
    /// images to look at; integer channels neither), creating the image in tev first if its
    /// size or channels changed.
    pub fn send(&mut self, image: &Image) -> Result<(), String> {
        let channels: Vec<(&str, &[f32])> = image
            .channels
            .iter()
            .filter(|c| !c.name.starts_with("Crypto"))
            .filter_map(|c| match &c.data {
                ChannelData::F32(v) => Some((c.name.as_str(), v.as_slice())),
                ChannelData::U32(_) => None,
            })
            .collect();
        let names: Vec<String> = channels.iter().map(|(n, _)| n.to_string()).collect();
        let shape = (image.width, image.height, names);
        if self.shown.as_ref() != Some(&shape) {
            let packet = create_image(&self.name, image.width, image.height, &shape.2);
            self.write(&packet)?;
            self.shown = Some(shape);
        }
        let rows = (MAX_PACKET_FLOATS / (image.width * channels.len()).max(1)).max(1);
        for y in (0..image.height).step_by(rows) {
            let height = rows.min(image.height - y);
            let packet = update_image(&self.name, &channels, image.width, y, height);
            self.write(&packet)?;
        }
        Ok(())
    }

    fn write(&mut self, packet: &[u8]) -> Result<(), String> {
        self.stream.write_all(packet).map_err(|e| format!("the display server went away: {e}"))
    }
}

/// A packet under construction: the length is filled in by [`Packet::finish`].
struct Packet(Vec<u8>);

impl Packet {
    fn new(kind: u8) -> Packet {
        let mut bytes = vec![0; 4];
        bytes.push(kind);
        Packet(bytes)
    }

    fn text(&mut self, s: &str) {
        // A NUL inside a name would end it early in tev: cut it there.
        self.0.extend(s.bytes().take_while(|&b| b != 0));
        self.0.push(0);
    }

    fn int(&mut self, i: usize) {
        self.0.extend_from_slice(&(i as i32).to_le_bytes());
    }

    fn finish(mut self) -> Vec<u8> {
        let length = self.0.len() as u32;
        self.0[..4].copy_from_slice(&length.to_le_bytes());
        self.0
    }
}

/// `CreateImage`: grab focus, name, width, height, channel count, channel names.
fn create_image(name: &str, width: usize, height: usize, channels: &[String]) -> Vec<u8> {
    let mut p = Packet::new(CREATE_IMAGE);
    p.0.push(1);
    p.text(name);
    p.int(width);
    p.int(height);
    p.int(channels.len());
    channels.iter().for_each(|c| p.text(c));
    p.finish()
}

/// `UpdateImage` (v3) of rows `y..y + height`: no focus grab, name, channel count, channel
/// names, x, y, width, height, per-channel offsets and strides (i64), then the channels one
/// after the other (offset `c × pixels`, stride 1).
fn update_image(name: &str, channels: &[(&str, &[f32])], width: usize, y: usize, height: usize) -> Vec<u8> {
    let pixels = width * height;
    let mut p = Packet::new(UPDATE_IMAGE_V3);
    p.0.reserve(pixels * channels.len() * 4 + 64 * channels.len());
    p.0.push(0);
    p.text(name);
    p.int(channels.len());
    channels.iter().for_each(|(c, _)| p.text(c));
    for v in [0, y, width, height] {
        p.int(v);
    }
    for c in 0..channels.len() {
        p.0.extend_from_slice(&((c * pixels) as i64).to_le_bytes());
    }
    for _ in channels {
        p.0.extend_from_slice(&1i64.to_le_bytes());
    }
    for (_, data) in channels {
        for value in &data[y * width..(y + height) * width] {
            p.0.extend_from_slice(&value.to_le_bytes());
        }
    }
    p.finish()
}
