# textile_fenicsx on Debian 13 (trixie): the same package list as bin/fenicsx-env's cached root.
#   docker build -t textile-fenicsx .
#   docker run --rm -v "$PWD/output:/work/output" textile-fenicsx
#   docker run --rm textile-fenicsx mpirun -n 4 python3 demos/orthogonal_3d.py
FROM debian:trixie

ENV DEBIAN_FRONTEND=noninteractive \
    OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 \
    OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 \
    OMPI_MCA_btl=self,sm PRTE_MCA_rmaps_default_mapping_policy=:oversubscribe \
    PYTHONDONTWRITEBYTECODE=1

COPY debian-packages.txt /tmp/debian-packages.txt
RUN apt-get update \
 && sed -e 's/#.*//' /tmp/debian-packages.txt | xargs apt-get install -y \
 && apt-get clean && rm -rf /var/lib/apt/lists/*

WORKDIR /work
COPY . /work
RUN pip install --no-deps --no-build-isolation --break-system-packages . \
 && textile-fenicsx --version

CMD ["python3", "demos/satin_4hs.py"]
