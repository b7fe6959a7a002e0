# The service image: runtime dependencies only (no torch, no anny).
FROM python:3.11-slim
WORKDIR /srv
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 \
    SPECTRAL_UNIONS_MODELS_DIR=/srv/models \
    SPECTRAL_UNIONS_DATABASE_PATH=/var/lib/spectral-unions/shapes.sqlite
COPY pyproject.toml README.md ./
COPY app ./app
COPY training ./training
COPY models ./models
RUN pip install --no-cache-dir . && mkdir -p /var/lib/spectral-unions && chown nobody /var/lib/spectral-unions
USER nobody
VOLUME /var/lib/spectral-unions
EXPOSE 8000
HEALTHCHECK CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz')"
CMD ["spectral-unions", "serve", "--host", "0.0.0.0", "--port", "8000"]
