"""The archive: database schema, transactional run archiving, raw-data store, queries."""
