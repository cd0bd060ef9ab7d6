"""Perception: protocols and backends that turn images and text into masks and unit embeddings."""
