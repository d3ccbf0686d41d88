//! One Parquet file written a batch of rows at a time: the rows of a table are pushed value
//! by value in column order, handed to the Parquet writer every [`BATCH_ROWS`] rows, and
//! the writer closes a row group every [`ROW_GROUP_ROWS`] rows, so memory stays bounded
//! however long the run.

use crate::columns::{Kind, Table};
use crate::ExportError;
use arrow_array::builder::{
    Float64Builder, StringBuilder, UInt32Builder, UInt64Builder, UInt8Builder,
};
use arrow_array::{ArrayRef, RecordBatch};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::basic::Compression;
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;
use std::collections::HashMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Rows gathered before they become one Arrow batch.
pub const BATCH_ROWS: usize = 1 << 16;
/// Rows of one Parquet row group.
pub const ROW_GROUP_ROWS: usize = 1 << 18;

/// One value of a row, in its column's type.
#[derive(Debug, Clone, Copy)]
pub enum Value<'a> {
    U64(u64),
    U32(u32),
    U8(u8),
    F64(f64),
    /// For an [`Kind::OptF64`] column.
    Opt(Option<f64>),
    Text(&'a str),
}

enum Builder {
    U64(UInt64Builder),
    U32(UInt32Builder),
    U8(UInt8Builder),
    F64(Float64Builder),
    Text(StringBuilder),
}

impl Builder {
    fn new(kind: Kind) -> Self {
        match kind {
            Kind::U64 => Self::U64(UInt64Builder::with_capacity(BATCH_ROWS)),
            Kind::U32 => Self::U32(UInt32Builder::with_capacity(BATCH_ROWS)),
            Kind::U8 => Self::U8(UInt8Builder::with_capacity(BATCH_ROWS)),
            Kind::F64 | Kind::OptF64 => Self::F64(Float64Builder::with_capacity(BATCH_ROWS)),
            Kind::Text => Self::Text(StringBuilder::new()),
        }
    }

    fn finish(&mut self) -> ArrayRef {
        match self {
            Self::U64(b) => Arc::new(b.finish()),
            Self::U32(b) => Arc::new(b.finish()),
            Self::U8(b) => Arc::new(b.finish()),
            Self::F64(b) => Arc::new(b.finish()),
            Self::Text(b) => Arc::new(b.finish()),
        }
    }
}

fn data_type(kind: Kind) -> DataType {
    match kind {
        Kind::U64 => DataType::UInt64,
        Kind::U32 => DataType::UInt32,
        Kind::U8 => DataType::UInt8,
        Kind::F64 | Kind::OptF64 => DataType::Float64,
        Kind::Text => DataType::Utf8,
    }
}

/// The Arrow schema of a table: each field's unit and meaning in its metadata.
pub fn schema(table: &Table) -> SchemaRef {
    let fields: Vec<Field> = table
        .columns
        .iter()
        .map(|c| {
            let meta = HashMap::from([
                ("unit".to_string(), c.unit.to_string()),
                ("description".to_string(), c.about.to_string()),
            ]);
            Field::new(c.name, data_type(c.kind), c.kind == Kind::OptF64).with_metadata(meta)
        })
        .collect();
    let meta = HashMap::from([
        ("fiberflow.table".to_string(), table.name.to_string()),
        ("fiberflow.row".to_string(), table.row.to_string()),
    ]);
    Arc::new(Schema::new_with_metadata(fields, meta))
}

/// A table being written.
pub struct TableWriter {
    table: Table,
    path: PathBuf,
    schema: SchemaRef,
    builders: Vec<Builder>,
    /// The column the next value goes to.
    cursor: usize,
    pending_rows: usize,
    rows: u64,
    writer: ArrowWriter<BufWriter<File>>,
}

impl TableWriter {
    /// Creates `dir/<table>.parquet`, with `metadata` (e.g. the run's id and launch file)
    /// as the file's key-value metadata.
    pub fn create(
        dir: &Path,
        table: Table,
        metadata: &[(String, String)],
    ) -> Result<Self, ExportError> {
        let path = dir.join(table.file_name());
        let file = File::create(&path).map_err(|e| ExportError::io(&path, e))?;
        let schema = schema(&table);
        let kv = metadata
            .iter()
            .map(|(k, v)| KeyValue::new(k.clone(), v.clone()))
            .collect();
        let props = WriterProperties::builder()
            .set_compression(Compression::SNAPPY)
            .set_max_row_group_row_count(Some(ROW_GROUP_ROWS))
            .set_created_by(format!("fiberflow {}", env!("CARGO_PKG_VERSION")))
            .set_key_value_metadata(Some(kv))
            .build();
        let writer = ArrowWriter::try_new(BufWriter::new(file), schema.clone(), Some(props))
            .map_err(|e| ExportError::parquet(&path, e))?;
        Ok(Self {
            builders: table.columns.iter().map(|c| Builder::new(c.kind)).collect(),
            table,
            path,
            schema,
            cursor: 0,
            pending_rows: 0,
            rows: 0,
            writer,
        })
    }

    /// Appends the next value of the current row (columns in the table's order).
    pub fn push(&mut self, v: Value<'_>) {
        let ok = match (self.builders.get_mut(self.cursor), v) {
            (Some(Builder::U64(b)), Value::U64(x)) => {
                b.append_value(x);
                true
            }
            (Some(Builder::U32(b)), Value::U32(x)) => {
                b.append_value(x);
                true
            }
            (Some(Builder::U8(b)), Value::U8(x)) => {
                b.append_value(x);
                true
            }
            (Some(Builder::F64(b)), Value::F64(x)) => {
                b.append_value(x);
                true
            }
            (Some(Builder::F64(b)), Value::Opt(x)) => {
                b.append_option(x);
                true
            }
            (Some(Builder::Text(b)), Value::Text(x)) => {
                b.append_value(x);
                true
            }
            _ => false,
        };
        // a value of the wrong type or past the last column is a bug in this crate's rows
        debug_assert!(ok, "{}: column {} got {v:?}", self.table.name, self.cursor);
        self.cursor += 1;
    }

    /// Appends several floats.
    pub fn push_f64s(&mut self, xs: &[f64]) {
        for &x in xs {
            self.push(Value::F64(x));
        }
    }

    /// Ends the current row; every [`BATCH_ROWS`] rows they go to the file.
    pub fn end_row(&mut self) -> Result<(), ExportError> {
        if self.cursor != self.builders.len() {
            return Err(ExportError::Internal(format!(
                "{}: a row of {} values for {} columns",
                self.table.name,
                self.cursor,
                self.builders.len()
            )));
        }
        self.cursor = 0;
        self.pending_rows += 1;
        self.rows += 1;
        if self.pending_rows >= BATCH_ROWS {
            self.write_batch()?;
        }
        Ok(())
    }

    fn write_batch(&mut self) -> Result<(), ExportError> {
        if self.pending_rows == 0 {
            return Ok(());
        }
        let arrays: Vec<ArrayRef> = self.builders.iter_mut().map(Builder::finish).collect();
        let batch = RecordBatch::try_new(self.schema.clone(), arrays)
            .map_err(|e| ExportError::Internal(format!("{}: {e}", self.table.name)))?;
        self.writer
            .write(&batch)
            .map_err(|e| ExportError::parquet(&self.path, e))?;
        self.pending_rows = 0;
        Ok(())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Adds a key-value pair to the file's metadata (written by [`Self::finish`]).
    pub fn add_metadata(&mut self, key: &str, value: &str) {
        self.writer
            .append_key_value_metadata(KeyValue::new(key.to_string(), value.to_string()));
    }

    /// Writes what is left and the file's footer; returns the rows written.
    pub fn finish(mut self) -> Result<u64, ExportError> {
        self.write_batch()?;
        let path = self.path.clone();
        self.writer
            .close()
            .map_err(|e| ExportError::parquet(&path, e))?;
        Ok(self.rows)
    }
}
