//! The exported tables and their columns: names, types, units and meanings in one place.
//! The Parquet files carry each column's unit and meaning in its field metadata, and
//! docs/export.md lists the same (test `docs_list_every_column`).

/// A column's value type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    U64,
    U32,
    U8,
    F64,
    /// A float that is null where the run did not record it (e.g. the hydrodynamic force of
    /// a one-way run).
    OptF64,
    Text,
}

/// One column of a table.
#[derive(Debug, Clone, Copy)]
pub struct Column {
    pub name: &'static str,
    pub kind: Kind,
    /// "" for a pure number or an index.
    pub unit: &'static str,
    pub about: &'static str,
}

/// One exported table (one Parquet file).
#[derive(Debug, Clone, Copy)]
pub struct Table {
    /// Its name on the command line (`--what`) and its file's stem.
    pub name: &'static str,
    /// What one row is.
    pub row: &'static str,
    pub columns: &'static [Column],
}

impl Table {
    pub fn file_name(&self) -> String {
        format!("{}.parquet", self.name)
    }
}

const fn c(name: &'static str, kind: Kind, unit: &'static str, about: &'static str) -> Column {
    Column {
        name,
        kind,
        unit,
        about,
    }
}

use Kind::*;

/// Wall units: lengths ν/u_τ, velocities u_τ, times ν/u_τ², forces ρ_f u_τ² (ν/u_τ)².
const LEN: &str = "wall units (nu/u_tau)";
const VEL: &str = "wall units (u_tau)";
const RATE: &str = "wall units (u_tau^2/nu)";
const TIME: &str = "wall units (nu/u_tau^2)";
const FORCE: &str = "wall units (rho_f u_tau^2 (nu/u_tau)^2)";

/// The leading columns of every table.
const STEP: [Column; 2] = [
    c("step", U64, "", "coupling step of the run (0 = the start)"),
    c("t_plus", F64, TIME, "time of the step"),
];

pub const STATES: Table = Table {
    name: "states",
    row: "one segment of one fibre at one recorded step (the recorder's complete states)",
    columns: &[
        STEP[0],
        STEP[1],
        c("group", Text, "", "fibre group (`[[fibers]] group` of the launch file)"),
        c("fiber", U32, "", "fibre index within its group (from 0; shards merged)"),
        c("segment", U32, "", "segment index along the fibre (from 0)"),
        c("segments", U32, "", "the fibre's number of segments N"),
        c("segment_length_plus", F64, LEN, "the fibre's segment length l"),
        c("diameter_plus", F64, LEN, "the fibre's diameter"),
        c("density_ratio", F64, "", "the fibre's solid to fluid density ratio"),
        c("layer", U8, "", "initial layer of the fibre (0 nearest the wall)"),
        c("centre_x_plus", F64, LEN, "segment centre, streamwise (unwrapped)"),
        c("centre_y_plus", F64, LEN, "segment centre, wall-normal (0 on the centreline)"),
        c("centre_z_plus", F64, LEN, "segment centre, spanwise (unwrapped)"),
        c("axis_x", F64, "", "segment unit axis, x component"),
        c("axis_y", F64, "", "segment unit axis, y component"),
        c("axis_z", F64, "", "segment unit axis, z component"),
        c("velocity_x_plus", F64, VEL, "segment centre velocity, x"),
        c("velocity_y_plus", F64, VEL, "segment centre velocity, y"),
        c("velocity_z_plus", F64, VEL, "segment centre velocity, z"),
        c("angular_velocity_x_plus", F64, RATE, "segment angular velocity, x"),
        c("angular_velocity_y_plus", F64, RATE, "segment angular velocity, y"),
        c("angular_velocity_z_plus", F64, RATE, "segment angular velocity, z"),
        c("hydro_force_x_plus", OptF64, FORCE, "hydrodynamic force of the fluid on the segment over the step that ended here, x (two-way runs; null one-way)"),
        c("hydro_force_y_plus", OptF64, FORCE, "as hydro_force_x_plus, y"),
        c("hydro_force_z_plus", OptF64, FORCE, "as hydro_force_x_plus, z"),
        c("contact_force_x_plus", F64, FORCE, "contact force of other segments on the segment over the step, x (0 when it touched nothing or the run has no contact)"),
        c("contact_force_y_plus", F64, FORCE, "as contact_force_x_plus, y"),
        c("contact_force_z_plus", F64, FORCE, "as contact_force_x_plus, z"),
        c("contacts", U32, "", "pairs the segment was in that touched in the step"),
    ],
};

pub const METRICS: Table = Table {
    name: "metrics",
    row: "one fibre at one step (the fibre nodes' metrics, every step)",
    columns: &[
        STEP[0],
        STEP[1],
        c("group", Text, "", "fibre group"),
        c("fiber", U32, "", "fibre index within its group"),
        c("centre_of_mass_x_plus", F64, LEN, "the fibre's mass-weighted centre, x (unwrapped)"),
        c("centre_of_mass_y_plus", F64, LEN, "the fibre's mass-weighted centre, y"),
        c("centre_of_mass_z_plus", F64, LEN, "the fibre's mass-weighted centre, z (unwrapped)"),
        c("z1", F64, "", "orientation z1 = z.e1 of the fibre's mean axis direction, in [-1, 1] (paper §4.3)"),
        c("sigma2", F64, "", "coiling sigma^2: the squared distances of the segment axes z_i from the mean direction z, summed, over N - 1 (paper §4.3; 0 straight)"),
        c("end_to_end_plus", F64, LEN, "distance between the fibre's two ends"),
    ],
};

pub const FLOW: Table = Table {
    name: "flow",
    row: "the flow solver's status at one step",
    columns: &[
        STEP[0],
        STEP[1],
        c("dt_plus", F64, TIME, "time step"),
        c("cfl", F64, "", "Courant number of the step"),
        c("max_divergence", F64, "", "largest absolute divergence of the velocity in the step (outer units)"),
        c("bulk_velocity_plus", F64, VEL, "bulk (mean) streamwise velocity"),
        c("re_tau", OptF64, "", "friction Reynolds number from the mean wall shear (null on steps without a wall-shear evaluation)"),
        c("pressure_gradient", F64, "outer units (u_tau^2/h)", "mean streamwise pressure gradient that drove the step (1 at constant pressure gradient)"),
        c("fiber_force_x_plus", OptF64, FORCE, "two-way: the fibres' total force on the fluid in the step, x (null one-way)"),
        c("fiber_force_y_plus", OptF64, FORCE, "as fiber_force_x_plus, y"),
        c("fiber_force_z_plus", OptF64, FORCE, "as fiber_force_x_plus, z"),
    ],
};

pub const PROFILES: Table = Table {
    name: "profiles",
    row: "one wall distance of the running flow statistics at one step (half channel, x-z and time averages since the run started)",
    columns: &[
        STEP[0],
        STEP[1],
        c("samples", U64, "", "flow fields averaged so far"),
        c("t_plus_span", F64, TIME, "time the averages span"),
        c("re_tau", F64, "", "friction Reynolds number from the mean wall shear"),
        c("bulk_velocity_plus", F64, VEL, "bulk velocity"),
        c("y_plus", F64, LEN, "distance from the wall"),
        c("u_mean_plus", F64, VEL, "mean streamwise velocity U+"),
        c("u_rms_plus", F64, VEL, "streamwise velocity fluctuation, RMS"),
        c("v_rms_plus", F64, VEL, "wall-normal velocity fluctuation, RMS"),
        c("w_rms_plus", F64, VEL, "spanwise velocity fluctuation, RMS"),
        c("uv_plus", F64, "wall units (u_tau^2)", "Reynolds shear stress <u'v'>"),
        c("omega_z_mean_plus", F64, RATE, "mean spanwise vorticity"),
        c("omega_x_rms_plus", F64, RATE, "streamwise vorticity, RMS"),
        c("omega_y_rms_plus", F64, RATE, "wall-normal vorticity, RMS"),
        c("omega_z_rms_plus", F64, RATE, "spanwise vorticity, RMS"),
    ],
};

pub const CONTACTS: Table = Table {
    name: "contacts",
    row: "one segment that touched another in the step ending at a recorded state",
    columns: &[
        STEP[0],
        STEP[1],
        c("group", Text, "", "fibre group"),
        c("fiber", U32, "", "fibre index within its group"),
        c("segment", U32, "", "segment index along the fibre"),
        c(
            "contact_force_x_plus",
            F64,
            FORCE,
            "contact force of other segments on it over the step, x",
        ),
        c(
            "contact_force_y_plus",
            F64,
            FORCE,
            "as contact_force_x_plus, y",
        ),
        c(
            "contact_force_z_plus",
            F64,
            FORCE,
            "as contact_force_x_plus, z",
        ),
        c("contacts", U32, "", "pairs it was in that touched"),
    ],
};

/// Every table, in the order `--what` lists them.
pub const ALL: [Table; 5] = [STATES, METRICS, FLOW, PROFILES, CONTACTS];

/// The table named `name`.
pub fn by_name(name: &str) -> Option<Table> {
    ALL.iter().copied().find(|t| t.name == name)
}

/// The Markdown table docs/export.md shows for `table` (its rows, header included).
pub fn markdown(table: &Table) -> String {
    let mut out = String::from("| column | type | unit | meaning |\n|---|---|---|---|\n");
    for c in table.columns {
        let ty = match c.kind {
            U64 => "uint64",
            U32 => "uint32",
            U8 => "uint8",
            F64 => "float64",
            OptF64 => "float64 (nullable)",
            Text => "string",
        };
        let unit = if c.unit.is_empty() { "–" } else { c.unit };
        out += &format!("| `{}` | {ty} | {unit} | {} |\n", c.name, c.about);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// docs/export.md shows every table's columns exactly as the files carry them.
    #[test]
    fn docs_list_every_column() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/export.md");
        let docs = std::fs::read_to_string(path).expect("docs/export.md");
        for t in ALL {
            let md = markdown(&t);
            assert!(
                docs.contains(&md),
                "docs/export.md lacks the table of {}:\n{md}",
                t.file_name()
            );
        }
    }

    /// Column names are unique within a table and free of Markdown's table separator.
    #[test]
    fn columns_are_unique_and_printable() {
        for t in ALL {
            let mut names: Vec<&str> = t.columns.iter().map(|c| c.name).collect();
            names.sort();
            names.dedup();
            assert_eq!(names.len(), t.columns.len(), "{}", t.name);
            for c in t.columns {
                assert!(
                    !c.about.contains('|') && !c.unit.contains('|'),
                    "{}",
                    c.name
                );
            }
        }
    }
}
