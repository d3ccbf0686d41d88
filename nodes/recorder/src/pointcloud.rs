//! `sensor_msgs/PointCloud2` of a fibre group's joints (x, y, z as float32, fibre id as
//! uint32), so generic MCAP viewers draw fibres as points with no converter.

use crate::ros::Header;
use fiberflow_messages::FiberGroupState;
use serde::Serialize;

#[derive(Serialize)]
struct PointField {
    name: String,
    offset: u32,
    datatype: u8,
    count: u32,
}
#[derive(Serialize)]
struct PointCloud2 {
    header: Header,
    height: u32,
    width: u32,
    fields: Vec<PointField>,
    is_bigendian: bool,
    point_step: u32,
    row_step: u32,
    data: Vec<u8>,
    is_dense: bool,
}

/// Encodes the joints of every fibre of a state as a CDR PointCloud2.
pub fn from_state(s: &FiberGroupState) -> Vec<u8> {
    let mut data = Vec::new();
    let mut count = 0u32;
    let mut seg = 0usize;
    for (fid, &n) in s.segments_per_fiber.iter().enumerate() {
        let n = n as usize;
        let l = s.segment_length.get(fid).copied().unwrap_or(0.0);
        let mut push = |p: [f64; 3]| {
            for c in p {
                data.extend_from_slice(&(c as f32).to_le_bytes());
            }
            data.extend_from_slice(&(fid as u32).to_le_bytes());
            count += 1;
        };
        for i in 0..n {
            let (c, z) = (
                &s.centre[3 * (seg + i)..3 * (seg + i) + 3],
                &s.axis[3 * (seg + i)..3 * (seg + i) + 3],
            );
            push([
                c[0] - 0.5 * l * z[0],
                c[1] - 0.5 * l * z[1],
                c[2] - 0.5 * l * z[2],
            ]);
            if i + 1 == n {
                push([
                    c[0] + 0.5 * l * z[0],
                    c[1] + 0.5 * l * z[1],
                    c[2] + 0.5 * l * z[2],
                ]);
            }
        }
        seg += n;
    }
    let pc = PointCloud2 {
        header: Header::at_t_plus(s.t_plus, "channel"),
        height: 1,
        width: count,
        fields: ["x", "y", "z"]
            .iter()
            .enumerate()
            .map(|(i, n)| PointField {
                name: n.to_string(),
                offset: 4 * i as u32,
                datatype: 7,
                count: 1,
            })
            .chain(std::iter::once(PointField {
                name: "fiber".into(),
                offset: 12,
                datatype: 6,
                count: 1,
            }))
            .collect(),
        is_bigendian: false,
        point_step: 16,
        row_step: 16 * count,
        data,
        is_dense: true,
    };
    cdr::serialize::<_, _, cdr::CdrLe>(&pc, cdr::Infinite).unwrap_or_default()
}
